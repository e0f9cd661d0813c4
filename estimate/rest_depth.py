"""Depth change of each point against the rest (undeformed) cloud of its session.

A pulled tissue's force shows in how far, and over how wide an area, its surface has left its
rest shape; a single normalised cloud hides both. The rest cloud is a session's first usable
frame (``vbfe live``: the run's first usable cloud, so start it with the tissue at rest). A
point's change is its ``z`` minus the mean depth of the ``NEIGHBOURS`` rest points nearest to
it in (x, y), found with scipy's k-d tree.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from vbfe.common.errors import EstimateError

NEIGHBOURS = 4


class RestDepth:
    """The rest cloud of a session, to measure the depth change of later clouds against."""

    def __init__(self, rest_points: np.ndarray) -> None:
        rest = np.asarray(rest_points, dtype=np.float64).reshape(-1, 3)
        rest = rest[np.isfinite(rest).all(axis=1)]
        if len(rest) == 0:
            raise EstimateError(
                "the rest cloud has no finite point; start from a frame where "
                "the tissue is seen at rest"
            )
        self._tree = cKDTree(rest[:, :2])
        self._z = rest[:, 2]
        self._k = min(NEIGHBOURS, len(rest))

    def change_m(self, points: np.ndarray) -> np.ndarray:
        """Depth change (N,) of points (N×3, finite, metres) against the rest surface."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        _, index = self._tree.query(points[:, :2], k=self._k)
        return points[:, 2] - self._z[index.reshape(len(points), -1)].mean(axis=1)

    def with_change(self, points: np.ndarray) -> np.ndarray:
        """Points with their depth change as a fourth column (N×4, float32)."""
        points = np.asarray(points).reshape(-1, 3)
        return np.column_stack([points, self.change_m(points)]).astype(np.float32)
