"""The depth-change image of a frame: how far the surface has left its rest shape, per cell.

The rest (first usable) cloud fixes a ``cells × cells`` grid over x, y (2nd–98th percentile of
its points) and a rest depth per cell (mean z of its points; cells without a rest point take
the nearest filled cell's, so every point inside the grid has a rest depth). A frame is kept as
two images: the sum of its points' depth change (z − rest depth of their cell) and their count,
so a thumbnail of any size that divides ``cells`` is the exact mean change over its larger
cells (``thumbnails``), computed from one pass over the points (``cell_passes.cell_sums``).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from vbfe.common.errors import EstimateError
from vbfe.estimate.cell_passes import cell_sums


class DepthChangeImage:
    """Depth change against a rest cloud on a fixed grid over x, y."""

    def __init__(self, rest_points: np.ndarray, cells: int) -> None:
        rest = np.asarray(rest_points, dtype=np.float64).reshape(-1, 3)
        rest = rest[np.isfinite(rest).all(axis=1)]
        if not len(rest):
            raise EstimateError(
                "the rest cloud has no finite point; start from a frame where "
                "the tissue is seen at rest"
            )
        self.cells = cells
        self._lo = np.percentile(rest[:, :2], 2, axis=0)
        hi = np.percentile(rest[:, :2], 98, axis=0)
        self._size = np.maximum(hi - self._lo, 1e-9) / cells
        total, count = cell_sums(rest, self._lo, self._size, cells, np.zeros(cells * cells))
        filled = count > 0
        mean = np.where(filled, total / np.maximum(count, 1), 0.0).reshape(cells, cells)
        nearest = ndimage.distance_transform_edt(
            ~filled.reshape(cells, cells), return_distances=False, return_indices=True
        )
        self._rest = mean[tuple(nearest)].ravel()

    def sums_counts(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sum of depth change, point count) per cell (cells × cells each, float32) of a
        cloud's finite points (N×3, metres)."""
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        total, count = cell_sums(points, self._lo, self._size, self.cells, self._rest)
        shape = (self.cells, self.cells)
        return total.reshape(shape).astype(np.float32), count.reshape(shape).astype(np.float32)


def thumbnails(sums: np.ndarray, counts: np.ndarray, size: int) -> np.ndarray:
    """Mean depth change (frames × size², metres; 0 where no point fell) of images
    (frames × cells × cells sums and counts) pooled to ``size × size``."""
    frames, cells = sums.shape[0], sums.shape[-1]
    if cells % size:
        raise EstimateError(f"thumbnail size {size} does not divide the image's {cells} cells")
    block = (frames, size, cells // size, size, cells // size)
    total = sums.reshape(block).sum(axis=(2, 4), dtype=np.float64)
    count = counts.reshape(block).sum(axis=(2, 4), dtype=np.float64)
    return np.where(count > 0, total / np.maximum(count, 1), 0.0).reshape(frames, size * size)
