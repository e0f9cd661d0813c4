"""Stages on their own threads joined by one-slot mailboxes: the newest item always wins.

Each stage takes the newest item its predecessor left, works on it and leaves the result for
the next stage; a stage slower than the one before it skips (and counts) the items it never
saw, and nothing queues. Throughput is set by the slowest stage, and stages overlap wherever
their work releases the GIL (OpenCV, numba, torch). Every item put in is, in the end, either
delivered to the sink, skipped, or dropped by a stage (which returned ``None`` or raised).
An item put ``pinned`` (a live run's first frame: its rest reference) is never skipped: each
stage takes it before the newest.
Beside a recording, each stage's thread runs at a lower priority than the recording's
(``yield_to_recording``: :func:`vbfe.common.priority.yield_to_recording`), as do the worker
threads it starts.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Any

from vbfe.common.mailbox import Mailbox
from vbfe.common.priority import yield_to_recording as lower_priority

_POLL_S = 0.2  # how often a waiting stage looks at the halt flag


class Pipeline:
    """``stages`` (name, function) in order; the last result goes to ``sink``. A function
    returning ``None`` drops its item. The first exception of any stage halts the pipeline
    and is kept in ``error`` (as ``"<stage>: <message>"``). With ``yield_to_recording`` the
    stages' threads lower their priority (a recording runs beside them)."""

    def __init__(
        self,
        stages: Sequence[tuple[str, Callable[[Any], Any]]],
        sink: Callable[[Any], None],
        yield_to_recording: bool = False,
    ) -> None:
        if not stages:
            raise ValueError("a pipeline needs at least one stage")
        self.names = tuple(name for name, _ in stages)
        self.inboxes: tuple[Mailbox, ...] = tuple(Mailbox() for _ in stages)
        self._sink = sink
        self._yield = yield_to_recording
        self._halt = threading.Event()
        self._flow = threading.Condition()  # guards _in_flight
        self._in_flight = 0  # items in a mailbox or in a stage's hands
        self._threads = [
            threading.Thread(
                target=self._run, args=(k, work), name=f"vbfe-live-{name}", daemon=True
            )
            for k, (name, work) in enumerate(stages)
        ]
        self.error: str | None = None

    def start(self) -> None:
        """Start every stage's thread."""
        for thread in self._threads:
            thread.start()

    def put(self, item: Any, pinned: bool = False) -> None:
        """Hand an item to the first stage (replacing one it has not taken yet, unless it or
        the waiting one is ``pinned``)."""
        self._hand_on(0, (item, pinned), entering=True)

    @property
    def skipped(self) -> int:
        """Items some stage never took because a newer one replaced them."""
        return sum(box.skipped for box in self.inboxes)

    def stop(self, drain_s: float = 5.0) -> None:
        """Let the items in flight through (at most ``drain_s``; put nothing more meanwhile),
        then stop every stage and wait for its thread to end."""
        with self._flow:
            self._flow.wait_for(lambda: self._in_flight == 0 or self._halt.is_set(), drain_s)
        self._halt.set()
        for thread in self._threads:
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join()

    def _hand_on(self, k: int, entry: tuple[Any, bool], entering: bool = False) -> None:
        """Put ``entry`` (item, pinned) in stage ``k``'s mailbox (the sink's after the last
        stage)."""
        with self._flow:
            if k == len(self.inboxes):
                self._in_flight -= 1
            else:
                box = self.inboxes[k]
                before = box.skipped
                box.put(entry, pinned=entry[1])
                if entering and box.skipped == before:
                    self._in_flight += 1
                elif not entering and box.skipped != before:
                    self._in_flight -= 1  # the item it replaced is gone
            self._flow.notify_all()

    def _drop(self) -> None:
        with self._flow:
            self._in_flight -= 1
            self._flow.notify_all()

    def _run(self, k: int, work: Callable[[Any], Any]) -> None:
        if self._yield:
            lower_priority()
        last = k == len(self.inboxes) - 1
        while not self._halt.is_set():
            entry = self.inboxes[k].take(_POLL_S)
            if entry is None:
                continue
            item, pinned = entry
            try:
                result = work(item)
                if result is None:
                    self._drop()
                    continue
                if last:
                    self._sink(result)
                self._hand_on(k + 1, (result, pinned))
            except Exception as exc:  # noqa: BLE001 - kept for the run to report
                if self.error is None:
                    self.error = f"{self.names[k]}: {exc}"
                self._halt.set()
                self._drop()
