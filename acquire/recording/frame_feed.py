"""The frames of an acquisition for a consumer that reads them one by one, like a camera
(calibration captures: ``calibrate capture``, ``projector-capture``, ``color``): each read asks
for one frame, so the camera runs in lock-step with the consumer, as when read directly."""

from __future__ import annotations

import contextlib
import queue
import time
from collections.abc import Iterator, Sequence

from vbfe.acquire.recording.acquisition import Acquisition
from vbfe.acquire.recording.listener import Listener
from vbfe.common.errors import DeviceError
from vbfe.drivers.camera.base import first_frame_after
from vbfe.drivers.rig import Rig
from vbfe.drivers.samples import StereoFrame

_PUT_POLL_S = 0.1


class FrameFeed(Listener):
    """Every frame, in order: ``read(timeout_s)`` and ``read_after(t_host_ns, timeout_s)`` as
    on a camera. The dispatch waits while ``size`` frames are not taken, so a paced camera
    loses none (a real-time one drops at its reader, as when it is read directly)."""

    def __init__(self, size: int = 1) -> None:
        self._frames: queue.Queue[StereoFrame] = queue.Queue(maxsize=size)
        self._acquisition: Acquisition  # from on_start, before any frame

    def on_start(self, acquisition: Acquisition) -> None:
        self._acquisition = acquisition

    def on_frames(self, frames: Sequence[StereoFrame]) -> None:
        for frame in frames:
            while not self._acquisition.halted:
                with contextlib.suppress(queue.Full):
                    self._frames.put(frame, timeout=_PUT_POLL_S)
                    break

    def read(self, timeout_s: float = 1.0) -> StereoFrame | None:
        """The next frame; ``None`` after ``timeout_s`` (a camera that is not real time, such
        as a simulation rendering each frame, is waited for as when read directly);
        DeviceError once the camera is gone."""
        acquisition = self._acquisition
        acquisition.demand()
        deadline = time.monotonic() + timeout_s
        while True:
            with contextlib.suppress(queue.Empty):
                return self._frames.get(timeout=min(_PUT_POLL_S, timeout_s))
            lost = acquisition.lost()
            if lost:
                raise DeviceError(lost)
            if acquisition.halted or (not acquisition.paced and time.monotonic() >= deadline):
                return None

    def read_after(self, t_host_ns: int, timeout_s: float = 1.0) -> StereoFrame | None:
        """The first frame that arrived at or after host time ``t_host_ns``."""
        return first_frame_after(self.read, t_host_ns, timeout_s)


@contextlib.contextmanager
def frame_feed(rig: Rig) -> Iterator[FrameFeed]:
    """Run an acquisition of ``rig`` (opened and closed around the block) that reads the camera
    on demand, and yield the feed of its frames."""
    feed = FrameFeed()
    with Acquisition(rig, queue_size=1, listeners=(feed,), on_demand=True):
        yield feed
