"""A one-item mailbox between a fast producer and a slower consumer: the newest item wins."""

from __future__ import annotations

import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class Mailbox(Generic[T]):
    """``put`` replaces an item not yet taken (counted in ``skipped``); ``take`` waits for one.

    Nothing queues without bound: a consumer slower than its producer always gets the newest
    item, and the ones it never saw are counted. A *pinned* item (the first frame of a live
    run: its rest reference) is never replaced: ``take`` returns it before the newest.
    """

    def __init__(self) -> None:
        self._item: T | None = None
        self._pinned: T | None = None
        self._ready = threading.Condition()
        self.put_count = 0
        self.skipped = 0

    def put(self, item: T, pinned: bool = False) -> None:
        """Leave ``item`` for the consumer, replacing (and counting) an untaken one; a pinned
        item waits beside the newest instead (one at a time)."""
        with self._ready:
            if pinned and self._pinned is None:
                self._pinned = item
            else:
                if self._item is not None:
                    self.skipped += 1
                self._item = item
            self.put_count += 1
            self._ready.notify()

    def take(self, timeout_s: float) -> T | None:
        """The pinned item if one waits, else the newest, or ``None`` when none came within
        ``timeout_s``."""
        with self._ready:
            if self._item is None and self._pinned is None:
                self._ready.wait(timeout_s)
            item: T | None
            if self._pinned is not None:
                item, self._pinned = self._pinned, None
            else:
                item, self._item = self._item, None
            return item
