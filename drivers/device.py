"""What every device has: open, close, and use as a context manager."""

from __future__ import annotations

import abc
from types import TracebackType
from typing import TypeVar

_D = TypeVar("_D", bound="Device")


class Device(abc.ABC):
    """A device that is acquired by ``open`` and released by ``close`` (both idempotent)."""

    @abc.abstractmethod
    def open(self) -> None:
        """Acquire the device; idempotent."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device; idempotent."""

    def __enter__(self: _D) -> _D:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
