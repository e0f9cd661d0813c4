"""The start/stop/context-manager frame shared by fakes that answer from a background thread."""

from __future__ import annotations

import abc
import threading
from types import TracebackType
from typing import TypeVar

T = TypeVar("T", bound="ThreadedFake")


class ThreadedFake(abc.ABC):
    """Runs ``_run`` in a daemon thread between ``start()`` and ``stop()`` (or a ``with`` block).

    ``_run`` must return soon after ``self._stop`` is set.
    """

    def __init__(self, name: str) -> None:
        self._name = name
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @abc.abstractmethod
    def _run(self) -> None:
        """The fake device's work loop."""

    def _cleanup(self) -> None:  # noqa: B027 - an optional hook: by default nothing to release
        """Release what the fake holds once its thread has ended."""

    def start(self: T) -> T:
        """Start the background thread."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread, wait for it, release resources."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self._cleanup()

    def __enter__(self: T) -> T:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
