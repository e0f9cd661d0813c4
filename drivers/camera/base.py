"""The stereo camera interface every camera backend implements."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from vbfe.drivers.device import SampleStream
from vbfe.drivers.samples import StereoFrame


def first_frame_after(
    read: Callable[[float], StereoFrame | None], t_host_ns: int, timeout_s: float
) -> StereoFrame | None:
    """The first frame ``read`` gives that arrived at or after host time ``t_host_ns`` (older
    ones are dropped, e.g. while a new projector pattern settles); ``None`` on a timeout."""
    while True:
        frame = read(timeout_s)
        if frame is None or frame.t_host_ns >= t_host_ns:
            return frame


class FrameSource(Protocol):
    """Frames read as from a camera: a :class:`StereoCamera`, or the frames an acquisition
    hands on (:class:`vbfe.acquire.recording.frame_feed.FrameFeed`)."""

    def read_after(self, t_host_ns: int, timeout_s: float = 1.0) -> StereoFrame | None:
        """The first frame that arrived at or after host time ``t_host_ns``; ``None`` on a
        timeout."""


class StereoCamera(SampleStream[StereoFrame]):
    """A stereo endoscope: open, read timestamped frame pairs, close.

    ``read`` (written once in :class:`~vbfe.drivers.device.SampleStream`) blocks for at most
    ``timeout_s`` and returns ``None`` when no frame arrived in time; it raises
    :class:`~vbfe.common.errors.DeviceError` when the device is gone. Backends implement
    ``_open``, ``_close`` and ``_read_sample(timeout_s)`` returning a frame with the device's
    own sequence number; sequence jumps are counted as dropped frames here.
    """

    stream = "camera"  # the session stream an acquisition reads it into
    width: int  # of one eye, pixels
    height: int
    fps: float

    def read_after(self, t_host_ns: int, timeout_s: float = 1.0) -> StereoFrame | None:
        """The first frame that arrived at or after host time ``t_host_ns`` (older ones are
        read and dropped, e.g. while a new projector pattern settles); ``None`` when a read
        times out."""
        return first_frame_after(self.read, t_host_ns, timeout_s)

    def describe(self) -> dict[str, object]:
        """Static facts about the device for session metadata."""
        return {
            "kind": type(self).__name__,
            "width": self.width,
            "height": self.height,
            "fps": self.fps,
        }
