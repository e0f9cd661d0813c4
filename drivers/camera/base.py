"""The stereo camera interface every camera backend implements."""

from __future__ import annotations

from vbfe.drivers.device import SampleStream
from vbfe.drivers.samples import StereoFrame


class StereoCamera(SampleStream[StereoFrame]):
    """A stereo endoscope: open, read timestamped frame pairs, close.

    ``read`` (written once in :class:`~vbfe.drivers.device.SampleStream`) blocks for at most
    ``timeout_s`` and returns ``None`` when no frame arrived in time; it raises
    :class:`~vbfe.drivers.errors.DeviceError` when the device is gone. Backends implement
    ``_open``, ``_close`` and ``_read_sample(timeout_s)`` returning a frame with the device's
    own sequence number; sequence jumps are counted as dropped frames here.
    """

    width: int  # of one eye, pixels
    height: int
    fps: float

    def describe(self) -> dict[str, object]:
        """Static facts about the device for session metadata."""
        return {"kind": type(self).__name__, "width": self.width, "height": self.height, "fps": self.fps}
