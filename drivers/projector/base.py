"""The projector interface every projector backend implements."""

from __future__ import annotations

import abc

import numpy as np

from vbfe.drivers.device import Device
from vbfe.drivers.samples import ProjectorEvent


class Projector(Device):
    """A projector that shows pattern images (BGR ``uint8``) and reports when it did."""

    width: int
    height: int

    @abc.abstractmethod
    def show(self, pattern: np.ndarray, name: str) -> ProjectorEvent:
        """Put ``pattern`` on the projector and return the event describing it."""

    def describe(self) -> dict[str, object]:
        """Static facts about the device for session metadata."""
        return {"kind": type(self).__name__, "width": self.width, "height": self.height}
