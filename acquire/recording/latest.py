"""The :class:`Latest` listener: what a view of a running acquisition shows (the newest frame,
the last seconds of every other stream, per-stream rates and clock offsets), kept for a GUI
thread to poll."""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from vbfe.acquire.recording.listener import Listener
from vbfe.acquire.session.layout import CAMERA
from vbfe.drivers.samples import StereoFrame

if TYPE_CHECKING:
    from vbfe.acquire.recording.acquisition import Acquisition

_RATE_WINDOW_S = 2.0  # rates are counted over this many seconds of host time


@dataclass(frozen=True)
class StreamView:
    """One stream as of now: records per second over the last seconds of their host times,
    the newest record's host-minus-device clock offset (``None`` when the device has no clock),
    and the records dispatched so far."""

    rate_hz: float
    clock_offset_s: float | None
    count: int


class Latest(Listener):
    """Keeps the newest stereo frame and the last ``window_s`` seconds of every other stream
    (``records(stream)``); safe to read from any thread while the dispatch thread writes.

    :param window_s: how much history of each non-camera stream is kept (host time).
    :param max_records: at most this many records kept per stream (bounds the memory of a fast
        stream; the newest win).
    """

    lossy = True  # a view: the newest frame is enough, and never at the recording's cost

    def __init__(self, window_s: float = 10.0, max_records: int = 20_000) -> None:
        self.window_s = window_s
        self.frame: StereoFrame | None = None
        self._records: dict[str, deque[Any]] = {}
        self._times: dict[str, deque[int]] = {}  # host times of the last seconds' records
        self._newest: dict[str, Any] = {}
        self._counts: dict[str, int] = {}
        self._max = max_records
        self._lock = threading.Lock()

    def on_start(self, acquisition: Acquisition) -> None:
        """A new acquisition: forget the previous one's records (they stay until then)."""
        with self._lock:
            self.frame = None
            for kept in (self._records, self._times, self._newest, self._counts):
                kept.clear()

    def on_records(self, stream: str, records: Sequence[Any]) -> None:
        with self._lock:
            if stream == CAMERA:
                self.frame = records[-1]
            else:
                kept = self._records.setdefault(stream, deque(maxlen=self._max))
                kept.extend(records)
                horizon = records[-1].t_host_ns - self.window_s * 1e9
                while kept and kept[0].t_host_ns < horizon:
                    kept.popleft()
            times = self._times.setdefault(stream, deque(maxlen=self._max))
            times.extend(r.t_host_ns for r in records)
            while times and times[0] < times[-1] - _RATE_WINDOW_S * 1e9:
                times.popleft()
            self._newest[stream] = records[-1]
            self._counts[stream] = self._counts.get(stream, 0) + len(records)

    def records(self, stream: str) -> list[Any]:
        """The kept records of a non-camera stream, oldest first."""
        with self._lock:
            return list(self._records.get(stream, ()))

    def streams(self) -> list[str]:
        """Every stream seen so far (the camera's included)."""
        with self._lock:
            return list(self._newest)

    def view(self, stream: str) -> StreamView:
        """Rate, clock offset and count of ``stream`` as of now."""
        with self._lock:
            times = self._times.get(stream, deque())
            span_ns = times[-1] - times[0] if len(times) > 1 else 0
            rate = (len(times) - 1) / (span_ns / 1e9) if span_ns > 0 else 0.0
            newest = self._newest.get(stream)
            count = self._counts.get(stream, 0)
        offset = None
        if newest is not None and getattr(newest, "t_device_ns", -1) >= 0:
            offset = (newest.t_host_ns - newest.t_device_ns) / 1e9
        return StreamView(rate, offset, count)
