"""Pacing on the host's monotonic clock: sleep until something is due."""

from __future__ import annotations

import time


def sleep_until(due_ns: int, timeout_s: float | None = None) -> bool:
    """Sleep until ``time.monotonic_ns()`` reaches ``due_ns``. When that is more than
    ``timeout_s`` away, sleep ``timeout_s`` only and return ``False``."""
    wait_s = (due_ns - time.monotonic_ns()) / 1e9
    if timeout_s is not None and wait_s > timeout_s:
        time.sleep(timeout_s)
        return False
    if wait_s > 0:
        time.sleep(wait_s)
    return True
