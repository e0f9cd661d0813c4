"""A one-item mailbox between a fast producer and a slower consumer: the newest item wins."""

from __future__ import annotations

import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class Mailbox(Generic[T]):
    """``put`` replaces an item not yet taken (counted in ``skipped``); ``take`` waits for one.

    Nothing queues without bound: a consumer slower than its producer always gets the newest
    item, and the ones it never saw are counted.
    """

    def __init__(self) -> None:
        self._item: T | None = None
        self._ready = threading.Condition()
        self.put_count = 0
        self.skipped = 0

    def put(self, item: T) -> None:
        """Leave ``item`` for the consumer, replacing (and counting) an untaken one."""
        with self._ready:
            if self._item is not None:
                self.skipped += 1
            self._item = item
            self.put_count += 1
            self._ready.notify()

    def take(self, timeout_s: float) -> T | None:
        """The newest item, or ``None`` when none came within ``timeout_s``."""
        with self._ready:
            if self._item is None:
                self._ready.wait(timeout_s)
            item, self._item = self._item, None
            return item
