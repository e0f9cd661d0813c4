"""How blurred a view's board is: the width of its square edges (10-90 % rise, px), measured
across the edges between neighbouring corners and averaged over the board."""

from __future__ import annotations

import cv2
import numpy as np

_REACH = 0.3  # the profile runs ±0.3 × the corner spacing across an edge (clear of markers)
_STEP_PX = 0.25


def neighbour_pairs(ids: np.ndarray, row_length: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into ``ids``) of corners next to each other on the board's grid (ids numbered
    row by row, ``row_length`` to a row): along rows and along columns."""
    where = {int(i): k for k, i in enumerate(ids)}
    first, second = [], []
    for k, i in enumerate(ids):
        i = int(i)
        for j in (i + 1 if (i + 1) % row_length else -1, i + row_length):
            if j in where:
                first.append(k)
                second.append(where[j])
    return np.asarray(first, int), np.asarray(second, int)


def edge_width_px(grey: np.ndarray, ids: np.ndarray, corners: np.ndarray, row_length: int) -> float:
    """The 10-90 % width (px) of the board's edges, from the mean profile across the edges
    joining neighbouring corners (``ids`` row by row, ``row_length`` to a row); NaN when the
    detection holds no neighbours."""
    a, b = neighbour_pairs(ids, row_length)
    if len(a) == 0:
        return float("nan")
    start, end = corners[a], corners[b]
    middle = (start + end) / 2
    along = end - start
    spacing = np.linalg.norm(along, axis=1, keepdims=True)
    across = np.column_stack([-along[:, 1], along[:, 0]]) / spacing
    reach = _REACH * float(np.median(spacing))
    steps = np.arange(-reach, reach + 1e-9, _STEP_PX, dtype=np.float64)
    samples = middle[:, None, :] + steps[None, :, None] * across[:, None, :]
    profiles = cv2.remap(
        grey.astype(np.float32),
        samples[..., 0].astype(np.float32),
        samples[..., 1].astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    ends = max(2, len(steps) // 6)
    low, high = profiles[:, :ends].mean(axis=1), profiles[:, -ends:].mean(axis=1)
    rising = np.where((high > low)[:, None], profiles, profiles[:, ::-1])
    lo, hi = np.minimum(low, high)[:, None], np.maximum(low, high)[:, None]
    usable = (hi - lo).ravel() > 1e-3
    if not usable.any():
        return float("nan")
    mean = np.mean((rising[usable] - lo[usable]) / (hi[usable] - lo[usable]), axis=0)
    return float(_crossing(steps, mean, 0.9) - _crossing(steps, mean, 0.1))


def _crossing(steps: np.ndarray, profile: np.ndarray, level: float) -> float:
    """Where the rising profile first reaches ``level`` (linear interpolation)."""
    above = np.flatnonzero(profile >= level)
    if len(above) == 0 or above[0] == 0:
        return float(steps[0] if len(above) else steps[-1])
    k = above[0]
    t = (level - profile[k - 1]) / (profile[k] - profile[k - 1])
    return float(steps[k - 1] + t * (steps[k] - steps[k - 1]))
