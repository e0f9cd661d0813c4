"""Chessboard corners where the board's two edge lines cross (issue 40): each inner corner is
the crossing of the row edge and the column edge through it, each edge located in grey-level
profiles across it and fitted on both sides of the corner.

The profiles run in the board's local grid frame (the corner's vectors to its neighbours):
along each edge at symmetric distances ±t from the corner, each across the edge in the
direction of the other grid vector, so they stay clear of the other edge through the corner
and of the next parallel edges. In a profile, the edge is where the grey level crosses the
middle of its two ends (a line fitted to the samples around the crossing); a fit of the edge
points as a parabola in t gives the edge's position and direction at the corner, with its
bend (lens distortion) taken out; the two tangents cross at the new corner.

Why not the other refinements: for any blur that is the same turned by 180° (defocus, pixel
area, compression on average) an X-junction is the same turned by 180° about its corner, so
the profile pairs at ±t are too and the fit has no bias; a smooth illumination change
(vignetting) moves the middle level and the crossing together. Only pixels near the edges
enter, so noise in flat areas does not either. ``cornerSubPix`` weighs every pixel of its
square window (noise in flat areas, the neighbouring squares' edges where the board is seen
obliquely, and an outward bias on bent edges); the sector detector's ``ACCURACY`` corners
carry a scale bias on blurred boards (f 0.14 % off on noise-free 1080p renders with a σ 2 px
defocus, where these corners are within 0.001 %).
"""

from __future__ import annotations

import cv2
import numpy as np

EDGE_LINES = "edge lines"  # the refinement's name in calibration reports
_NEAR, _FAR = 0.05, 0.7  # profiles from 0.05 to 0.7 corner spacings either side of the corner
_PROFILES = 16  # per side and edge
_ACROSS = 0.45  # profile half-length in spacings: clear of the next parallel edge (at 1)
_ACROSS_PX = 24.0  # and in pixels at most (level ends on a large board; bounded work)
_STEP_PX = 0.5  # sample step along a profile, at most
_FIT_PX = 2.0  # the crossing refined by a line fitted to the samples within ±2 px of it
_ENDS = 8  # each profile's end levels: the mean of its first and last eighth
_ROUNDS = 3  # profiles placed around the last estimate


def grid_vectors(corners: np.ndarray, inner: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Each corner's (n×2 each) vector to its neighbours along the board's rows and columns:
    half the difference of the two neighbours (one-sided on the board's border)."""
    nx, ny = inner
    grid = corners.reshape(ny, nx, 2)
    rows, columns = np.empty_like(grid), np.empty_like(grid)
    for out, axis in ((rows, 1), (columns, 0)):
        g = np.moveaxis(grid, axis, 0)
        o = np.moveaxis(out, axis, 0)
        o[1:-1] = (g[2:] - g[:-2]) / 2
        o[0], o[-1] = g[1] - g[0], g[-1] - g[-2]
    return rows.reshape(-1, 2), columns.reshape(-1, 2)


def _crossings(profiles: np.ndarray, s: np.ndarray, fit: np.ndarray) -> tuple[np.ndarray, ...]:
    """Where each profile (…×m, sampled at ``s``) crosses the middle of its end levels, nearest
    its centre and refined by a line through the samples within ``fit`` (…, in ``s`` units) of
    the crossing; and each profile's contrast (end to end; 0 where it does not cross)."""
    ends = max(2, len(s) // _ENDS)
    low, high = profiles[..., :ends].mean(axis=-1), profiles[..., -ends:].mean(axis=-1)
    level = profiles - ((low + high) / 2)[..., None]
    above = level * np.sign(high - low)[..., None] > 0
    steps = np.abs(np.arange(len(s) - 1) - (len(s) - 2) / 2)
    change = above[..., 1:] != above[..., :-1]
    k = np.where(change, steps, np.inf).argmin(axis=-1)[..., None]
    y0 = np.take_along_axis(level, k, -1)[..., 0]
    y1 = np.take_along_axis(level, k + 1, -1)[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        first = s[k[..., 0]] + np.where(y1 != y0, y0 / (y0 - y1), 0.5) * (s[1] - s[0])
        x = s - first[..., None]
        w = (np.abs(x) <= fit[..., None]).astype(np.float64)
        n, sx, sy = w.sum(-1), (w * x).sum(-1), (w * level).sum(-1)
        slope = (n * (w * x * level).sum(-1) - sx * sy) / (n * (w * x * x).sum(-1) - sx * sx)
        refined = first - (sy - slope * sx) / n / slope
    good = np.isfinite(refined) & (np.abs(refined - first) < (s[1] - s[0]) * 2)
    return np.where(good, refined, first), np.where(change.any(axis=-1), high - low, 0.0)


def _tangent(
    grey: np.ndarray, corners: np.ndarray, along: np.ndarray, across: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The edge through each corner in the direction ``along``: a point on it next to the
    corner and its direction there (n×2 each), from profiles in the direction ``across``."""
    n = len(corners)
    across = across * np.minimum(_ACROSS, _ACROSS_PX / np.linalg.norm(across, axis=1))[:, None]
    spans = np.linalg.norm(across, axis=1)  # each profile's half-length, px
    m = int(np.ceil(2 * spans.max() / _STEP_PX)) | 1
    s = np.linspace(-1.0, 1.0, m)
    points = (
        corners[:, None, None]
        + t[None, :, None, None] * along[:, None, None]
        + s[None, None, :, None] * across[:, None, None]
    ).reshape(n, -1, 2)
    profiles = cv2.remap(
        grey,
        np.ascontiguousarray(points[..., 0], np.float32),
        np.ascontiguousarray(points[..., 1], np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).reshape(n, len(t), m)
    offset, contrast = _crossings(profiles.astype(np.float64), s, (_FIT_PX / spans)[:, None])
    # the edge as offset = c0 + c1 t + c2 t², weighted by the profiles' contrast²
    design = np.stack([np.ones_like(t), t, t * t], axis=1)
    weighted = design.T[None] * (contrast**2)[:, None, :]
    coef = np.linalg.solve(weighted @ design[None], (weighted @ offset[..., None]))[..., 0]
    return corners + coef[:, :1] * across, along + coef[:, 1:2] * across


def edge_line_corners(
    grey: np.ndarray, corners: np.ndarray, inner: tuple[int, int]
) -> np.ndarray | None:
    """The chessboard's inner corners (n×2, numbered row by row, ``inner`` = (nx, ny)) moved
    to where the board's edges cross in ``grey``; ``None`` when a corner cannot be placed (an
    edge without contrast)."""
    image = np.asarray(grey, np.float32)
    q = np.asarray(corners, np.float64).reshape(-1, 2)
    rows, columns = grid_vectors(q, inner)
    side = np.linspace(_NEAR, _FAR, _PROFILES)
    t = np.concatenate([-side[::-1], side])
    try:
        for _ in range(_ROUNDS):
            normals, offsets = [], []
            for along, across in ((rows, columns), (columns, rows)):
                point, direction = _tangent(image, q, along, across, t)
                normals.append(np.column_stack([-direction[:, 1], direction[:, 0]]))
                offsets.append(np.sum(normals[-1] * point, axis=1))
            q = np.linalg.solve(np.stack(normals, axis=1), np.stack(offsets, axis=1)[..., None])
            q = q[..., 0]
    except np.linalg.LinAlgError:
        return None
    return q if np.all(np.isfinite(q)) else None
