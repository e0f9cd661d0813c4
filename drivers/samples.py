"""What devices deliver: timestamped stereo frames, force samples and projector events.

Every timestamp is ``int64`` nanoseconds. ``t_device_ns`` is the device's own clock (kernel
buffer time, trocar counter time, ...), ``t_host_ns`` is the host's ``time.monotonic_ns()`` when
the sample reached the driver (or the simulated host clock on the bench). ``seq`` is the
device's sequence number, so gaps can be told from slow readers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class StereoFrame:
    """One left/right image pair (BGR ``uint8``, H×W×3 each)."""

    left: np.ndarray
    right: np.ndarray
    seq: int
    t_device_ns: int
    t_host_ns: int
    encoded: tuple[bytes, bytes] | None = None  # the camera's own JPEG bytes, when it sent MJPEG


@dataclass(frozen=True)
class ForceSample:
    """One trocar reading: force along the trocar axes in newtons (x, y, z)."""

    force_n: np.ndarray
    seq: int
    t_device_ns: int
    t_host_ns: int


@dataclass(frozen=True)
class ProjectorEvent:
    """A pattern was put on the projector: which pattern, with which frame-ID stamp, when."""

    pattern: str
    frame_id: int
    seq: int
    t_host_ns: int
    t_device_ns: int = -1  # projectors without a clock report -1


@dataclass
class StreamStats:
    """Counters a driver keeps while reading, for drop/gap reporting."""

    received: int = 0
    dropped: int = 0  # samples the device produced that never arrived (sequence gaps, late frames)
    malformed: int = 0  # frames that arrived but could not be decoded
    gaps: list[tuple[int, int]] = field(default_factory=list)  # (last good seq, next good seq)
