"""Peak surface displacement of a frame relative to the session's first frame.

The first usable frame fixes a grid over x, y (2nd–98th percentile of its points, up to 16×16
cells, fewer for sparse clouds so that a cell holds ~8 reference points); every frame's
depth map on that grid is the per-cell median z. The peak displacement is the largest absolute
depth change over cells that have at least ``MIN_CELL_POINTS`` points in both frames, after a
3×3-cell median filter of the change map (one outlier cell, e.g. at an occlusion edge, cannot
make the peak; a pulled region spanning a few cells does).
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from vbfe.estimate.cell_passes import cell_medians

MIN_CELL_POINTS = 3
MAX_CELLS = 16
POINTS_PER_CELL = 8


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
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        depth = cell_medians(points, self._lo, self._size, self.cells, MIN_CELL_POINTS)
        return depth.reshape(self.cells, self.cells)

    def peak_displacement_m(self, points: np.ndarray) -> float:
        """Largest |depth change| vs the reference over cells seen in both (NaN if none)."""
        change = np.pad(
            np.abs(self.depth_map(points) - self.reference_depth_m), 1, constant_values=np.nan
        )
        with warnings.catch_warnings():  # all-NaN neighbourhoods are expected at the borders
            warnings.simplefilter("ignore", RuntimeWarning)
            smoothed = np.nanmedian(sliding_window_view(change, (3, 3)), axis=(-2, -1))
        return float(np.nanmax(smoothed)) if np.isfinite(smoothed).any() else float("nan")
