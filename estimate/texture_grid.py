"""A cloud laid back on its camera's pixel grid, in one compiled pass (``texture_motion.py``).

Each finite point in front of the camera (``z > 0``) goes to the grid cell nearest its
``(x/z, y/z)``; its texture value there is its least colour channel over that channel's
ambient level. Where several points fall in one cell the last wins.
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
        xyz[i, j, 0], xyz[i, j, 1], xyz[i, j, 2], xyz[i, j, 3] = x, y, z, 1.0
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
    (x/z, y/z) with pitch ``step``: its points and seen mask (rows × cols × 4, float32) and
    its texture and seen mask (rows × cols × 2), 0 where unseen; ``ambient``: each colour
    channel's unlit level (float32)."""
    xyz = np.zeros(shape + (4,), np.float32)
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
