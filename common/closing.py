"""What a ``with`` block closes on leaving: files, devices, the rig."""

from __future__ import annotations

import abc
from types import TracebackType
from typing import TypeVar

_C = TypeVar("_C", bound="ClosedOnExit")


class ClosedOnExit(abc.ABC):
    """A context manager that returns itself and calls :meth:`close` on leaving the block
    (a subclass that must open first overrides ``__enter__``)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release what the object holds."""

    def __enter__(self: _C) -> _C:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
