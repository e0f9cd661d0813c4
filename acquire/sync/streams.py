"""A third clock check: an extra stream's motion (a robot's joints) against the force.

Where the force kinks (a pull starts or stops) the robot that pulls starts or stops moving at
the same instant, so its joint positions kink too. The same corner fit that aligns the images
with the force (:func:`~vbfe.acquire.sync.corners.corner_offset`) aligns the stream's channels
with it: the lag says by how much the stream's host times (its publisher's clock mapped through
LSL's time correction) differ from the force's, independently of the camera.
"""

from __future__ import annotations

import numpy as np

from vbfe.acquire.session.reader import SessionReader
from vbfe.acquire.sync.corners import OffsetEstimate, corner_offset
from vbfe.common.errors import SessionError

_MAX_RATE_HZ = 250.0  # faster streams are averaged in blocks down to this (the fit's cost)


def _block_means(t_ns: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Times and values averaged in blocks of consecutive samples, to at most _MAX_RATE_HZ."""
    span_s = (t_ns[-1] - t_ns[0]) / 1e9
    block = int(len(t_ns) / (span_s * _MAX_RATE_HZ)) if span_s > 0 else 1
    if block <= 1:
        return t_ns, values
    n = len(t_ns) // block * block
    return (
        t_ns[:n].reshape(-1, block).mean(axis=1).astype(np.int64),
        values[:n].reshape(-1, block, values.shape[1]).mean(axis=1),
    )


def stream_offset(reader: SessionReader, name: str, max_lag_s: float = 0.25) -> OffsetEstimate:
    """Lag (s) by which the motion in extra stream ``name`` follows the force (positive: the
    stream is stamped later than the force of the same instant). SessionError when the stream
    holds markers, does not move, or the force has no corner inside it."""
    stream = reader.stream(name)
    if stream.values is None or len(stream) < 3:  # markers
        raise SessionError(f"stream {name} has no motion to check the clocks with")
    values = stream.values[:, np.ptp(stream.values, axis=0) > 0]
    if values.shape[1] == 0:
        raise SessionError(f"stream {name} never moves, so it has no motion onset")
    t_ns, values = _block_means(stream.t_host_ns, values - values.mean(axis=0))
    estimate = corner_offset(t_ns, values, reader.force_times_ns(), reader.forces_n(), max_lag_s)
    estimate.method = f"{name} motion at the force corners"
    return estimate
