"""A cloud laid back on its camera's pixel grid, and the displacement field with its seen
weight, each in one compiled pass (``texture_motion.py``).

Each finite point in front of the camera (``z > 0``) goes to the grid cell nearest its
``(x/z, y/z)``; its texture value there is its least colour channel over that channel's
ambient level (where several points fall in one cell the last wins). Its coordinates go to a
grid of half the columns: each point adds half of itself and of its seen weight to the cell of
its column pair (the points are smoothed over several columns anyway, ``POINT_SMOOTH_PX``).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _fill(
    points: np.ndarray,
    colors: np.ndarray,
    lo: np.ndarray,
    step: np.ndarray,
    ambient: np.ndarray,
    xyz: np.ndarray,
    texture: np.ndarray,
) -> None:
    rows, cols = texture.shape[:2]
    for k in range(points.shape[0]):
        x, y, z = float(points[k, 0]), float(points[k, 1]), float(points[k, 2])
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z) and z > 0):
            continue
        col = np.rint((x / z - lo[0]) / step[0])
        row = np.rint((y / z - lo[1]) / step[1])
        if not (0 <= col < cols and 0 <= row < rows):
            continue
        i, j = int(row), int(col)
        half = j // 2
        xyz[i, half, 0] += 0.5 * x
        xyz[i, half, 1] += 0.5 * y
        xyz[i, half, 2] += 0.5 * z
        xyz[i, half, 3] += 0.5
        value = colors[k, 0] / ambient[0]
        for c in range(1, 3):
            value = min(value, colors[k, c] / ambient[c])
        texture[i, j, 0], texture[i, j, 1] = value, 1.0


def grid_maps(
    points: np.ndarray,
    colors: np.ndarray,
    lo: np.ndarray,
    step: np.ndarray,
    ambient: np.ndarray,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """A cloud (N×3, m; colours N×3 float32) on the grid whose cell (0, 0) is at ``lo``
    (x/z, y/z) with pitch ``step``: its points and seen weight on the grid of half the columns
    (rows × ⌈cols/2⌉ × 4, float32; column pairs averaged, 0 where unseen) and its texture and
    seen mask (rows × cols × 2), 0 where unseen; ``ambient``: each colour channel's unlit level
    (float32)."""
    xyz = np.zeros((shape[0], (shape[1] + 1) // 2, 4), np.float32)
    texture = np.zeros(shape + (2,), np.float32)
    _fill(
        points,
        colors,
        np.asarray(lo, np.float64),
        np.asarray(step, np.float64),
        ambient,
        xyz,
        texture,
    )
    return xyz, texture


@numba.njit(cache=True, nogil=True, inline="always")
def _pair_place(j: int, pairs: int) -> tuple[int, int, float, float]:
    """Pixel column ``j`` on a grid of column pairs (pair ``k`` centred on column ``2k + 0.5``):
    the two pairs around it and their shares (0 beyond the grid)."""
    place = (j - 0.5) * 0.5
    k = int(np.floor(place))
    t = place - k
    lo = 1.0 - t if k >= 0 else 0.0
    hi = t if k + 1 < pairs else 0.0
    return max(k, 0), min(k + 1, pairs - 1), lo, hi


@numba.njit(cache=True, nogil=True)
def _points(blurred: np.ndarray, points: np.ndarray) -> None:
    cols = points.shape[1]
    place = [_pair_place(j, blurred.shape[1]) for j in range(cols)]
    for i in range(points.shape[0]):
        for j in range(cols):
            k0, k1, lo, hi = place[j]
            weight = lo * blurred[i, k0, 3] + hi * blurred[i, k1, 3]
            seen = weight > 0.5
            for c in range(3):  # divided only where seen: the weight may be 0 elsewhere
                value = lo * blurred[i, k0, c] + hi * blurred[i, k1, c]
                points[i, j, c] = value / weight if seen else np.nan
            points[i, j, 3] = 1.0 if seen else 0.0


def smoothed_points(blurred: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The smoothed points at every pixel of the grid (``shape``) with their seen mask
    (rows × cols × 4, float32; NaN and 0 where under half the neighbourhood is seen) from the
    column pairs' blur (values and weight; pair ``k`` centred on column ``2k + 0.5``), by
    interpolation along the rows."""
    points = np.empty(shape + (4,), np.float32)
    _points(blurred, points)
    return points


@numba.njit(cache=True, nogil=True)
def _field(points: np.ndarray, flow: np.ndarray, rest: np.ndarray, weighted: np.ndarray) -> None:
    rows, cols = rest.shape[:2]
    for i in range(rows):
        for j in range(cols):
            x, y = j + flow[i, j, 0], i + flow[i, j, 1]
            x0, y0 = int(np.floor(x)), int(np.floor(y))
            seen = rest[i, j, 3] > 0 and 0 <= x0 and x0 + 1 < cols and 0 <= y0 and y0 + 1 < rows
            if seen:  # the four pixels around, each of them seen
                seen = (
                    points[y0, x0, 3] > 0
                    and points[y0, x0 + 1, 3] > 0
                    and points[y0 + 1, x0, 3] > 0
                    and points[y0 + 1, x0 + 1, 3] > 0
                )
            if seen:
                ax, ay = x - x0, y - y0
                for c in range(3):
                    top = (1 - ax) * points[y0, x0, c] + ax * points[y0, x0 + 1, c]
                    bottom = (1 - ax) * points[y0 + 1, x0, c] + ax * points[y0 + 1, x0 + 1, c]
                    weighted[i, j, c] = (1 - ay) * top + ay * bottom - rest[i, j, c]
                weighted[i, j, 3] = 1.0
            else:
                for c in range(4):
                    weighted[i, j, c] = 0.0


def weighted_field(points: np.ndarray, flow: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """The 3D displacement of every rest pixel with its seen mask (rows × cols × 4, float32,
    0 where unseen): the frame's smoothed ``points`` (:func:`smoothed_points`) interpolated
    where the ``flow`` (rows × cols × 2, pixels) takes the pixel, seen where the four pixels
    around are, minus the ``rest``'s (the same, of the rest cloud)."""
    weighted = np.empty(rest.shape, np.float32)
    _field(points, np.ascontiguousarray(flow), rest, weighted)
    return weighted


@numba.njit(cache=True, nogil=True)
def _pairs(values: np.ndarray, pairs: np.ndarray) -> None:
    cols = values.shape[1]
    for i in range(values.shape[0]):
        for k in range(pairs.shape[1]):
            for c in range(values.shape[2]):
                right = values[i, 2 * k + 1, c] if 2 * k + 1 < cols else 0.0
                pairs[i, k, c] = 0.5 * (values[i, 2 * k, c] + right)


def column_pairs(values: np.ndarray) -> np.ndarray:
    """A grid (rows × cols × channels, float32) at half its columns: each pair's mean (a
    zero column after an odd count)."""
    pairs = np.empty((values.shape[0], (values.shape[1] + 1) // 2, values.shape[2]), np.float32)
    _pairs(values, pairs)
    return pairs


@numba.njit(cache=True, nogil=True)
def _peak(blurred: np.ndarray, inner: np.ndarray) -> float:
    cols = inner.shape[1]
    place = [_pair_place(j, blurred.shape[1]) for j in range(cols)]
    peak = 0.0
    for i in range(inner.shape[0]):
        for j in range(cols):
            if not inner[i, j]:
                continue
            k0, k1, lo, hi = place[j]
            weight = lo * blurred[i, k0, 3] + hi * blurred[i, k1, 3]
            squared = 0.0
            for c in range(3):
                value = lo * blurred[i, k0, c] + hi * blurred[i, k1, c]
                squared += value * value
            if weight > 0:
                peak = max(peak, squared / (weight * weight))
    return np.sqrt(peak)


def peak_magnitude(blurred: np.ndarray, inner: np.ndarray) -> float:
    """The largest magnitude, over the ``inner`` pixels (rows × cols bool), of a normalised
    blur of 3D values on a grid of column pairs (values and weight, as
    :func:`smoothed_points` reads it)."""
    return float(_peak(blurred, inner))


@numba.njit(cache=True, nogil=True)
def _grey(
    texture: np.ndarray, blurred: np.ndarray, low: float, scale: float, grey: np.ndarray
) -> None:
    floor = np.float32(1e-6)
    for i in range(texture.shape[0]):
        for j in range(texture.shape[1]):
            if texture[i, j, 1] > 0:
                value = texture[i, j, 0]
            else:  # a hole: its neighbours' normalised blur
                value = blurred[i, j, 0] / max(blurred[i, j, 1], floor)
            level = (np.float64(value) - low) * scale
            grey[i, j] = np.uint8(min(max(level, 0.0), 255.0))


def grey_image(texture: np.ndarray, blurred: np.ndarray, low: float, scale: float) -> np.ndarray:
    """The texture (rows × cols × 2: value and seen mask) with its holes filled from
    ``blurred`` (its normalised blur: values and weight), as 8-bit grey: ``(value - low) ·
    scale`` clipped to 0–255."""
    grey = np.empty(texture.shape[:2], np.uint8)
    _grey(texture, blurred, low, scale, grey)
    return grey
