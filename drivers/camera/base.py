"""The stereo camera interface every camera backend implements."""

from __future__ import annotations

import abc

from vbfe.drivers.device import Device
from vbfe.drivers.samples import StereoFrame, StreamStats


class StereoCamera(Device):
    """A stereo endoscope: open, read timestamped frame pairs, close.

    ``read`` blocks for at most ``timeout_s`` and returns ``None`` when no frame arrived in time;
    it raises :class:`~vbfe.drivers.errors.DeviceError` when the device is gone.
    """

    width: int  # of one eye, pixels
    height: int
    fps: float

    def __init__(self) -> None:
        self.stats = StreamStats()

    @abc.abstractmethod
    def read(self, timeout_s: float = 1.0) -> StereoFrame | None:
        """The next frame pair, or ``None`` on timeout."""

    def describe(self) -> dict[str, object]:
        """Static facts about the device for session metadata."""
        return {"kind": type(self).__name__, "width": self.width, "height": self.height, "fps": self.fps}
