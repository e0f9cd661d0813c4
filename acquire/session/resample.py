"""Values of a sampled signal at other instants (e.g. a stream at the frames' times)."""

from __future__ import annotations

import numpy as np


def resample_at(t_ns: np.ndarray, values: np.ndarray, at_ns: np.ndarray,
                max_gap_ns: float) -> np.ndarray:
    """``values`` (``(n, k)``, sampled at ``t_ns``) linearly interpolated at ``at_ns``:
    ``(len(at_ns), k)``. Instants outside the samples, or inside a gap between two samples
    longer than ``max_gap_ns``, get NaN rather than an invented value."""
    values = np.asarray(values, np.float64).reshape(len(t_ns), -1)
    out = np.full((len(at_ns), values.shape[1]), np.nan)
    if len(t_ns) < 2 or len(at_ns) == 0:
        return out
    order = np.argsort(t_ns, kind="stable")
    t, values = np.asarray(t_ns)[order], values[order]
    x = (np.asarray(at_ns) - t[0]).astype(np.float64)
    xp = (t - t[0]).astype(np.float64)
    for k in range(values.shape[1]):
        out[:, k] = np.interp(x, xp, values[:, k], left=np.nan, right=np.nan)
    right = np.clip(np.searchsorted(xp, x), 1, len(xp) - 1)
    out[(xp[right] - xp[right - 1]) > max_gap_ns] = np.nan
    return out
