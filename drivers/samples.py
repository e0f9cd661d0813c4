"""What devices deliver: timestamped stereo frames, force samples and projector events.

Every timestamp is ``int64`` nanoseconds. ``t_device_ns`` is the device's own clock (kernel
buffer time, trocar counter time, ...), ``t_host_ns`` is the host's ``time.monotonic_ns()`` when
the sample reached the driver (or the simulated host clock on the bench). ``seq`` is the
device's sequence number, so gaps can be told from slow readers.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import cv2
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


class JpegStereoFrame(StereoFrame):
    """A frame pair as the camera's own JPEG bytes (``encoded``), decoded on first access to
    ``left``/``right`` only: recording it in ``mjpeg`` storage never decodes it."""

    encoded: tuple[bytes, bytes]
    _decoded: dict[int, np.ndarray]
    _lock: threading.Lock

    def __init__(
        self, encoded: tuple[bytes, bytes], seq: int, t_device_ns: int, t_host_ns: int
    ) -> None:
        for name, value in (
            ("encoded", encoded),
            ("seq", seq),
            ("t_device_ns", t_device_ns),
            ("t_host_ns", t_host_ns),
        ):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "_decoded", {})
        object.__setattr__(self, "_lock", threading.Lock())

    def _eye(self, index: int) -> np.ndarray:
        with self._lock:
            if index not in self._decoded:
                image = cv2.imdecode(np.frombuffer(self.encoded[index], np.uint8), cv2.IMREAD_COLOR)
                if image is None:
                    raise ValueError(f"frame {self.seq}: the camera's JPEG does not decode")
                self._decoded[index] = image
            return self._decoded[index]

    def __repr__(self) -> str:
        return (
            f"JpegStereoFrame(seq={self.seq}, t_device_ns={self.t_device_ns}, "
            f"t_host_ns={self.t_host_ns}, jpeg bytes={[len(b) for b in self.encoded]})"
        )

    left = property(lambda self: self._eye(0), doc="Left eye, BGR (decoded on first use).")
    right = property(lambda self: self._eye(1), doc="Right eye, BGR (decoded on first use).")


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
    errors: int = 0  # error frames / bus state changes the interface reported
    _marks: list[GapMark] = field(default_factory=list, repr=False)

    def mark_gap(
        self, reason: str, last_seq: int, next_seq: int, t_host_ns: int, count: int
    ) -> None:
        """Record an event the sequence numbers do not show (an error frame, a bus state
        change) for the session file's gaps; ``reason`` is one of the session gap reasons."""
        self._marks.append(GapMark(reason, last_seq, next_seq, int(t_host_ns), int(count)))

    def take_marks(self) -> list[GapMark]:
        """The gaps marked since the last call (for the recorder to store)."""
        marks, self._marks = self._marks, []
        return marks


@dataclass(frozen=True)
class GapMark:
    """An event a device saw between sample ``last_seq`` and ``next_seq`` (-1: not yet known)."""

    reason: str
    last_seq: int
    next_seq: int
    t_host_ns: int
    count: int
