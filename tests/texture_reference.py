"""The texture feature (``estimate/texture_motion.py``) as it was computed before the compiled
grid and the one-pass normalised blurs, numpy throughout: the reference the fast path must keep
(within 2 %), read by the texture tests and ``benchmarks/bench_texture_speed.py``."""

import cv2
import numpy as np

from vbfe.estimate import texture_motion as tm


def reference_peak(rest_points, rest_colors, points, colors):
    """The texture feature as it was computed before the compiled grid and the one-pass
    normalised blurs (numpy throughout): the reference the fast path must keep."""

    def blur(image, sigma, aspect):
        return cv2.GaussianBlur(image, (0, 0), sigmaX=sigma, sigmaY=max(sigma * aspect, 0.3))

    def weighted(values, seen, sigma, aspect):
        filled = np.where(seen[..., None] if values.ndim == 3 else seen, values, 0)
        return blur(filled.astype(np.float32), sigma, aspect), blur(
            seen.astype(np.float32), sigma, aspect
        )

    rest_points = np.asarray(rest_points, np.float64)
    keep = np.isfinite(rest_points).all(axis=1) & (rest_points[:, 2] > 0)
    rest_points, rest_colors = rest_points[keep], np.asarray(rest_colors, np.float32)[keep]
    step = np.asarray(tm.pixel_steps(rest_points))
    aspect = step[0] / step[1]
    pixels = rest_points[:, :2] / rest_points[:, 2:]
    lo = pixels.min(axis=0) - 2 * step
    cols, rows = (np.ceil((pixels.max(axis=0) - lo) / step) + 3).astype(int)
    ambient = np.maximum(np.percentile(rest_colors, tm.AMBIENT_PERCENTILE, axis=0), 1.0)

    def maps(p, c):
        p = np.asarray(p, np.float64)
        ok = np.isfinite(p).all(axis=1) & (p[:, 2] > 0)
        p, c = p[ok], np.asarray(c, np.float32)[ok]
        ij = np.rint((p[:, :2] / p[:, 2:] - lo) / step).astype(np.int64)
        inside = ((ij >= 0) & (ij < [cols, rows])).all(axis=1)
        xyz = np.full((rows, cols, 3), np.nan, np.float32)
        texture = np.full((rows, cols), np.nan, np.float32)
        xyz[ij[inside, 1], ij[inside, 0]] = p[inside]
        texture[ij[inside, 1], ij[inside, 0]] = (c[inside] / ambient).min(axis=1)
        return xyz, texture

    def smoothed(xyz):
        total, weight = weighted(xyz, np.isfinite(xyz).all(axis=-1), tm.POINT_SMOOTH_PX, aspect)
        return np.where(
            (weight > 0.5)[..., None], total / np.maximum(weight, 1e-6)[..., None], np.nan
        )

    def grey(texture, low, high):
        seen = np.isfinite(texture)
        total, weight = weighted(texture, seen, tm.FILL_PX, aspect)
        filled = np.where(seen, texture, total / np.maximum(weight, 1e-6))
        return np.clip((filled - low) * 255.0 / (high - low), 0, 255).astype(np.uint8)

    rest_xyz, rest_texture = maps(rest_points, rest_colors)
    low, high = np.nanpercentile(rest_texture, tm.CONTRAST_PERCENTILES)
    xyz, texture = maps(points, colors)
    flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(
        grey(rest_texture, low, high), grey(texture, low, high), None
    )
    grid = np.mgrid[0:rows, 0:cols].astype(np.float32)
    moved = cv2.remap(
        smoothed(xyz).astype(np.float32),
        grid[1] + flow[..., 0],
        grid[0] + flow[..., 1],
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=(np.nan,) * 3,
    )
    field = moved - smoothed(rest_xyz)
    seen = np.isfinite(field).all(axis=-1)
    border = np.ones((2 * max(1, round(tm.BORDER_PX * aspect)) + 1, 2 * tm.BORDER_PX + 1), np.uint8)
    inner = cv2.erode(seen.astype(np.uint8), border) > 0
    total, weight = weighted(field, seen, tm.SMOOTH_PX, aspect)
    return float((np.linalg.norm(total[inner], axis=-1) / weight[inner]).max())
