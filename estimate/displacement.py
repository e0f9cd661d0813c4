"""Peak surface displacement of a frame relative to the session's first frame.

The first usable frame fixes a grid over x, y (2nd–98th percentile of its points, up to 16×16
cells, fewer for sparse clouds so that a cell holds ~8 reference points); every frame's
depth map on that grid is the per-cell median z. The peak displacement is the largest absolute
depth change over cells that have at least ``MIN_CELL_POINTS`` points in both frames, after a
3×3-cell median filter of the change map (one outlier cell, e.g. at an occlusion edge, cannot
make the peak; a pulled region spanning a few cells does). The per-cell medians are one
compiled pass (numba), for ``vbfe live``.
"""

from __future__ import annotations

import warnings

import numba
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

MIN_CELL_POINTS = 3
MAX_CELLS = 16
POINTS_PER_CELL = 8


@numba.njit(cache=True, nogil=True)
def _cell_medians(
    points: np.ndarray, lo: np.ndarray, size: np.ndarray, cells: int, min_points: int
) -> np.ndarray:
    """Median z of the points in each cell of the grid (flat, NaN under ``min_points``): the
    points binned by cell (counting sort), each cell's few depths sorted on their own."""
    n = points.shape[0]
    cell = np.full(n, -1, np.int64)
    count = np.zeros(cells * cells, np.int64)
    for k in range(n):
        if not (np.isfinite(points[k, 0]) and np.isfinite(points[k, 1])):
            continue
        i = int(np.floor((points[k, 0] - lo[0]) / size[0]))
        j = int(np.floor((points[k, 1] - lo[1]) / size[1]))
        if 0 <= i < cells and 0 <= j < cells:
            cell[k] = i * cells + j
            count[cell[k]] += 1
    start = np.zeros(cells * cells + 1, np.int64)
    for c in range(cells * cells):
        start[c + 1] = start[c] + count[c]
    z = np.empty(start[-1], np.float64)
    fill = start[:-1].copy()
    for k in range(n):
        if cell[k] >= 0:
            z[fill[cell[k]]] = points[k, 2]
            fill[cell[k]] += 1
    depth = np.full(cells * cells, np.nan)
    for c in range(cells * cells):
        m = count[c]
        if m >= min_points:
            zs = np.sort(z[start[c] : start[c + 1]])
            depth[c] = (zs[m // 2] + zs[(m - 1) // 2]) / 2
    return depth


class DisplacementGrid:
    """Depth-change measurement against a reference cloud (the session's first frame)."""

    def __init__(self, reference: np.ndarray, cells: int | None = None) -> None:
        if cells is None:
            cells = int(np.clip(np.sqrt(len(reference) / POINTS_PER_CELL), 2, MAX_CELLS))
        lo = np.percentile(reference[:, :2], 2, axis=0)
        hi = np.percentile(reference[:, :2], 98, axis=0)
        self.cells = cells
        self._lo = lo
        self._size = np.maximum(hi - lo, 1e-9) / cells
        self.reference_depth_m = self.depth_map(reference)

    def depth_map(self, points: np.ndarray) -> np.ndarray:
        """Per-cell median z (cells × cells, metres); NaN where a cell has too few points."""
        return _cell_medians(
            np.asarray(points, np.float64).reshape(-1, 3),
            np.asarray(self._lo, np.float64),
            np.asarray(self._size, np.float64),
            self.cells,
            MIN_CELL_POINTS,
        ).reshape(self.cells, self.cells)

    def peak_displacement_m(self, points: np.ndarray) -> float:
        """Largest |depth change| vs the reference over cells seen in both (NaN if none)."""
        change = np.pad(
            np.abs(self.depth_map(points) - self.reference_depth_m), 1, constant_values=np.nan
        )
        with warnings.catch_warnings():  # all-NaN neighbourhoods are expected at the borders
            warnings.simplefilter("ignore", RuntimeWarning)
            smoothed = np.nanmedian(sliding_window_view(change, (3, 3)), axis=(-2, -1))
        return float(np.nanmax(smoothed)) if np.isfinite(smoothed).any() else float("nan")
