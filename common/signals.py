"""Ctrl-C and SIGTERM: one exception for each, and a prompt stop of worker processes."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import signal
import threading
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import NoReturn

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that every cleanup for an interrupt runs."""


PR_SET_PDEATHSIG = 1


def die_with_parent() -> None:
    """Ask Linux to send this (worker) process SIGTERM when its parent dies, even by SIGKILL;
    elsewhere nothing happens."""
    with contextlib.suppress(OSError, AttributeError, TypeError):
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def raise_for(signum: int) -> NoReturn:
    """Raise what ``signum`` means: :class:`Terminated` for SIGTERM, else KeyboardInterrupt."""
    raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While the block runs, SIGTERM raises :class:`Terminated` in the main thread (when it was
    left at its default action)."""
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
    ):
        yield
        return
    signal.signal(signal.SIGTERM, lambda signum, frame: raise_for(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def kill_workers(pool: ProcessPoolExecutor) -> bool:
    """Kill ``pool``'s workers and let its manager thread see them gone. A worker killed half
    way through sending a result (clouds are large) leaves a partial message in the result
    pipe, and the manager thread then waits for the rest forever (CPython 3.11): once the
    workers are dead, closing the parent's copy of the pipe's write end turns that wait into
    end-of-file, and the pool reports itself broken. False: it had no workers."""
    children = list((getattr(pool, "_processes", None) or {}).values())
    for child in children:
        child.terminate()
    for child in children:
        child.join(timeout=5.0)
    writer = getattr(getattr(pool, "_result_queue", None), "_writer", None)
    if writer is not None and not any(child.is_alive() for child in children):
        writer.close()
    return bool(children)


@contextlib.contextmanager
def stop_pool_on_signals(pool: ProcessPoolExecutor) -> Iterator[None]:
    """While ``pool``'s workers compute for this block, SIGINT and SIGTERM kill them at once
    and the block ends with KeyboardInterrupt or :class:`Terminated`, whatever exception the
    broken pool raised. (The handler raises only while the pool has no workers: an exception
    raised from a handler lands wherever the main thread is, and Python swallows it inside a
    finalizer.) Signals that are ignored stay ignored; outside the main thread this does
    nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def on_signal(signum: int, frame: object) -> None:
        received.append(signum)
        if not kill_workers(pool):
            raise_for(signum)

    previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    for sig, handler in previous.items():
        if handler is not signal.SIG_IGN:
            signal.signal(sig, on_signal)
    try:
        yield
    except BaseException:
        if received:
            raise_for(received[0])
        raise
    finally:
        for sig, handler in previous.items():
            if handler is not None:
                signal.signal(sig, handler)
    if received:
        raise_for(received[0])
