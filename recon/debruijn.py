"""Window codes of De Bruijn sequences (every window of ``order`` symbols occurs once), for
decoding; the sequence itself is :func:`vbfe.drivers.projector.pattern.de_bruijn`."""

from __future__ import annotations

import numpy as np


def window_codes(symbols: np.ndarray, n_symbols: int = 3, order: int = 4) -> np.ndarray:
    """Codes ``sum(s[i+k] * n**k)`` of the ``len - order + 1`` full (non-wrapping) windows."""
    s = np.asarray(symbols, dtype=np.int64)
    n_windows = len(s) - order + 1
    if n_windows <= 0:
        return np.zeros(0, dtype=np.int64)
    weights = n_symbols ** np.arange(order, dtype=np.int64)
    windows = np.lib.stride_tricks.sliding_window_view(s, order)
    return windows @ weights


def code_lookup(symbols: np.ndarray, n_symbols: int = 3, order: int = 4) -> np.ndarray:
    """Table ``code -> index of the window's first symbol`` (``-1`` for codes not in ``symbols``).

    Raises ``ValueError`` if a code occurs twice, i.e. ``symbols`` is not window-unique.
    """
    codes = window_codes(symbols, n_symbols, order)
    if len(np.unique(codes)) != len(codes):
        raise ValueError(f"sequence is not unique in windows of {order}")
    table = np.full(n_symbols**order, -1, dtype=np.int32)
    table[codes] = np.arange(len(codes), dtype=np.int32)
    return table
