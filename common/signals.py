"""Ctrl-C and SIGTERM: one exception for each, and a prompt stop of worker processes."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import multiprocessing
import signal
import threading
from collections.abc import Iterator
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
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return
    signal.signal(signal.SIGTERM, lambda signum, frame: raise_for(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextlib.contextmanager
def stop_workers_on_signals() -> Iterator[None]:
    """While worker processes compute for this block, SIGINT and SIGTERM terminate them at once
    and the block ends with KeyboardInterrupt or :class:`Terminated`, whatever exception the
    broken pool raised. (An exception raised from a handler lands wherever the main thread
    is, and Python swallows it inside a finalizer: the run then went on to the end.) Signals
    that are ignored stay ignored; outside the main thread this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def on_signal(signum: int, frame: object) -> None:
        received.append(signum)
        children = multiprocessing.active_children()
        for child in children:
            child.terminate()
        if not children:
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
