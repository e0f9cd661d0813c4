"""The per-point passes of a frame's preparation, compiled: each a loop over the cloud's points
(some 200,000 at 640×360) where NumPy took several passes and temporary arrays.

They give exactly NumPy's results (the same IEEE operations in the same order; a cell's median
from its middle depths, as a sort of every point by cell then depth gave it): the features
prepared for training, evaluation and ``vbfe live`` do not change, only their cost
(``benchmarks/bench_train.py`` times the preparation).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def finite_rows(points: np.ndarray) -> np.ndarray:
    """The rows of ``points`` (N×3) whose three coordinates are finite, as float64."""
    keep = np.empty(points.shape[0], dtype=np.bool_)
    n = 0
    for k in range(points.shape[0]):
        keep[k] = (
            np.isfinite(points[k, 0]) and np.isfinite(points[k, 1]) and np.isfinite(points[k, 2])
        )
        n += keep[k]
    out = np.empty((n, 3), dtype=np.float64)
    row = 0
    for k in range(points.shape[0]):
        if keep[k]:
            for c in range(3):
                out[row, c] = points[k, c]
            row += 1
    return out


@njit(cache=True, nogil=True)
def _cell(points: np.ndarray, k: int, lo: np.ndarray, size: np.ndarray, cells: int) -> int:
    """Flat index of the cell of point ``k`` on the grid of :func:`grid_cells`, -1 outside."""
    i = np.floor((points[k, 0] - lo[0]) / size[0])
    j = np.floor((points[k, 1] - lo[1]) / size[1])
    if 0 <= i < cells and 0 <= j < cells:
        return int(i) * cells + int(j)
    return -1


@njit(cache=True, nogil=True)
def grid_cells(
    points: np.ndarray, lo: np.ndarray, size: np.ndarray, cells: int
) -> tuple[np.ndarray, np.ndarray]:
    """Flat index (0 outside) of the cell of a ``cells`` × ``cells`` grid over x, y (from
    ``lo`` in steps of ``size``) each point (N×3, float64, finite) falls in, and whether it
    lies inside the grid."""
    n = points.shape[0]
    cell = np.zeros(n, dtype=np.int64)
    inside = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        c = _cell(points, k, lo, size, cells)
        if c >= 0:
            cell[k] = c
            inside[k] = True
    return cell, inside


@njit(cache=True, nogil=True)
def _select(values: np.ndarray, k: int) -> float:
    """The ``k``-th smallest of ``values``, moved to ``values[k]`` with every smaller one
    before it (Hoare's selection; NumPy's ``partition`` takes 10 s to compile here)."""
    lo, hi = 0, len(values) - 1
    while lo < hi:
        pivot = values[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:  # between the two parts: equal to the pivot
            break
    return values[k]


@njit(cache=True, nogil=True)
def cell_medians(
    points: np.ndarray, lo: np.ndarray, size: np.ndarray, cells: int, min_points: int
) -> np.ndarray:
    """Per-cell median z (cells², NaN where fewer than ``min_points`` points fell) of points
    (N×3, float64, finite) on the grid of :func:`grid_cells`: the points counted into their
    cells, each cell's middle depths selected (a sort's, in a third of its time)."""
    cell, inside = grid_cells(points, lo, size, cells)
    n_cells = cells * cells
    count = np.zeros(n_cells + 1, dtype=np.int64)
    for k in range(points.shape[0]):
        if inside[k]:
            count[cell[k] + 1] += 1
    start = count  # counts → where each cell's depths start, in place
    for c in range(n_cells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    z = np.empty(start[-1], dtype=np.float64)
    for k in range(points.shape[0]):
        if inside[k]:
            z[fill[cell[k]]] = points[k, 2]
            fill[cell[k]] += 1
    depth = np.empty(n_cells)
    for c in range(n_cells):
        m = start[c + 1] - start[c]
        depth[c] = np.nan
        if m >= min_points:
            values = z[start[c] : start[c + 1]]
            upper = _select(values, m // 2)
            lower = upper
            if m % 2 == 0:
                lower = values[0]
                for v in values[1 : m // 2]:
                    lower = max(lower, v)
            depth[c] = (upper + lower) / 2
    return depth


@njit(cache=True, nogil=True)
def cell_sums(
    points: np.ndarray, lo: np.ndarray, size: np.ndarray, cells: int, rest: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-cell sum of ``z - rest[cell]`` and count (cells² each, float64) of the points
    (N×3, float64, finite) inside the grid of :func:`grid_cells`, summed in point order."""
    total = np.zeros(cells * cells)
    count = np.zeros(cells * cells)
    for k in range(points.shape[0]):
        c = _cell(points, k, lo, size, cells)
        if c >= 0:
            total[c] += points[k, 2] - rest[c]
            count[c] += 1.0
    return total, count


def warm_up() -> None:
    """Load (or, the first time, compile: about 5 s) every pass for float32 and float64
    clouds, so that a live run's first frame does not pay for it."""
    for dtype in (np.float32, np.float64):
        points = finite_rows(np.ones((4, 3), dtype))
    lo, size = np.zeros(2), np.ones(2)
    cell_medians(points, lo, size, 2, 1)
    cell_sums(points, lo, size, 2, np.zeros(4))
