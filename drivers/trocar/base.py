"""The force sensor interface every trocar backend implements."""

from __future__ import annotations

import abc

import numpy as np

from vbfe.drivers.device import Device
from vbfe.drivers.samples import ForceSample, StreamStats


class ForceSensor(Device):
    """A force sensor (the TRF85D trocar): open, read timestamped samples, tare, close.

    ``read`` returns ``None`` on timeout, raises :class:`~vbfe.drivers.errors.DeviceError` when
    the interface is gone (bus-off, unplugged), and never raises for one bad frame: it counts it
    in ``stats.malformed`` and goes on.
    """

    rate_hz: float
    axes: tuple[str, ...] = ("x", "y", "z")

    def __init__(self) -> None:
        self.stats = StreamStats()
        self.offset_n = np.zeros(len(self.axes))

    @abc.abstractmethod
    def read(self, timeout_s: float = 1.0) -> ForceSample | None:
        """The next tared force sample, or ``None`` on timeout."""

    def describe(self) -> dict[str, object]:
        """Static facts about the device for session metadata."""
        return {"kind": type(self).__name__, "rate_hz": self.rate_hz, "axes": list(self.axes)}
