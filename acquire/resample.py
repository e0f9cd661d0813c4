"""Force (or any sampled signal) at other instants, such as frame times: written once."""

from __future__ import annotations

import numpy as np


def resample_at(
    times_ns: np.ndarray,
    sample_times_ns: np.ndarray,
    values: np.ndarray,
    max_gap_ns: float | None = None,
) -> np.ndarray:
    """``values`` (n × k, at ``sample_times_ns``, any order) linearly interpolated at
    ``times_ns``: NaN outside the samples, and inside a gap longer than ``max_gap_ns``, rather
    than an invented value. Returns ``(len(times_ns), k)``."""
    times = np.asarray(times_ns, np.int64)
    values = np.asarray(values, np.float64)
    values = values[:, None] if values.ndim == 1 else values
    out = np.full((len(times), values.shape[1]), np.nan)
    if len(sample_times_ns) < 2 or len(times) == 0:
        return out
    order = np.argsort(sample_times_ns, kind="stable")
    t, values = np.asarray(sample_times_ns, np.int64)[order], values[order]
    x, xp = (times - t[0]).astype(np.float64), (t - t[0]).astype(np.float64)  # exact offsets
    for k in range(values.shape[1]):
        out[:, k] = np.interp(x, xp, values[:, k], left=np.nan, right=np.nan)
    if max_gap_ns is not None:
        right = np.clip(np.searchsorted(xp, x), 1, len(xp) - 1)
        out[(xp[right] - xp[right - 1]) > max_gap_ns] = np.nan
    return out
