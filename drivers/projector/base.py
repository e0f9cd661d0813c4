"""The projector interface every projector backend implements."""

from __future__ import annotations

import abc
import time
from collections.abc import Callable

import numpy as np

from vbfe.drivers.device import Device
from vbfe.drivers.samples import ProjectorEvent


class Projector(Device):
    """A projector that shows pattern images (BGR ``uint8``) and reports when it did.

    ``show`` is written once: the open guard, the event's sequence number and host time.
    Backends implement ``_open``, ``_close`` and ``_show(pattern, name, seq)``, which puts the
    pattern up and returns the frame ID it carries (-1 when the projector cannot stamp one).
    """

    width: int
    height: int

    def __init__(self, host_clock: Callable[[], int] = time.monotonic_ns) -> None:
        self._host_clock = host_clock
        self._seq = 0

    def show(self, pattern: np.ndarray, name: str) -> ProjectorEvent:
        """Put ``pattern`` on the projector and return the event describing it."""
        self.require_open()
        frame_id = self._show(pattern, name, self._seq)
        event = ProjectorEvent(
            pattern=name, frame_id=int(frame_id), seq=self._seq, t_host_ns=int(self._host_clock())
        )
        self._seq += 1
        return event

    @abc.abstractmethod
    def _show(self, pattern: np.ndarray, name: str, seq: int) -> int:
        """Backend hook: show ``pattern`` as event ``seq``; the frame ID it carries, or -1."""

    def describe(self) -> dict[str, object]:
        """Static facts about the device for session metadata."""
        return {"kind": type(self).__name__, "width": self.width, "height": self.height}
