"""The projector interface every projector backend implements."""

from __future__ import annotations

import abc
from types import TracebackType

import numpy as np

from vbfe.drivers.samples import ProjectorEvent


class Projector(abc.ABC):
    """A projector that shows pattern images (BGR ``uint8``) and reports when it did."""

    width: int
    height: int

    @abc.abstractmethod
    def open(self) -> None:
        """Acquire the projector; idempotent."""

    @abc.abstractmethod
    def show(self, pattern: np.ndarray, name: str) -> ProjectorEvent:
        """Put ``pattern`` on the projector and return the event describing it."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the projector; idempotent."""

    def describe(self) -> dict[str, object]:
        """Static facts about the device for session metadata."""
        return {"kind": type(self).__name__, "width": self.width, "height": self.height}

    def __enter__(self) -> "Projector":
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
