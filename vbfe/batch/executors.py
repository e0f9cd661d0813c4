"""Run one task per session: in local worker processes (the default) or on a Ray cluster.

Each task runs in a process of its own, so a session that crashes or kills its worker fails
alone: it is reported with its reason and the others go on. Outcomes arrive as tasks finish.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
import re
import signal
import socket
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from vbfe.common.errors import EXIT_TERMINATED, BatchError, VbfeError
from vbfe.common.signals import die_with_parent, raise_for

EXECUTORS = ("local", "ray")


@dataclass
class TaskOutcome:
    """The result of one task: ``value`` when ``ok``, else a one-line ``error``."""

    item: str
    ok: bool
    value: Any = None
    error: str = ""


def _call(fn: Callable[[str], Any], item: str) -> tuple[bool, Any]:
    """Run a task, turning any exception into a one-line reason."""
    try:
        return True, fn(item)
    except VbfeError as exc:
        return False, " ".join(str(exc).split())  # one line, whatever HDF5 put in it
    except Exception as exc:  # noqa: BLE001 - a batch reports every failure and goes on
        return False, f"{type(exc).__name__}: {' '.join(str(exc).split())}"


def _child(
    fn: Callable[[str], Any], item: str, conn: multiprocessing.connection.Connection
) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    signal.signal(signal.SIGTERM, lambda signum, frame: raise_for(signum))  # cleanups run
    die_with_parent()
    try:
        conn.send(_call(fn, item))
    except KeyboardInterrupt:  # the parent's SIGTERM (Terminated): cleanups ran, no traceback
        raise SystemExit(EXIT_TERMINATED) from None
    conn.close()


def _died(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        return f"worker killed by signal {signal.Signals(-exitcode).name}"
    return f"worker exited with status {exitcode} before reporting"


def run_local(
    fn: Callable[[str], Any], items: Sequence[str], workers: int | None = None
) -> Iterator[TaskOutcome]:
    """Tasks in at most ``workers`` spawned processes (default: one per CPU core)."""
    ctx = multiprocessing.get_context("spawn")
    pending = list(items)
    workers = max(1, workers or os.cpu_count() or 1)
    running: dict[Any, tuple[Any, str]] = {}
    try:
        while pending or running:
            while pending and len(running) < workers:
                item = pending.pop(0)
                receive, send = ctx.Pipe(duplex=False)
                process = ctx.Process(target=_child, args=(fn, item, send), daemon=True)
                process.start()
                send.close()
                running[receive] = (process, item)
            ready = multiprocessing.connection.wait(list(running))
            for conn in [c for c in list(running) if c in ready]:
                process, item = running.pop(conn)
                try:
                    ok, payload = conn.recv()
                except EOFError:
                    ok, payload = False, None
                conn.close()
                process.join()
                if payload is None and not ok:
                    payload = _died(process.exitcode)
                yield TaskOutcome(item, ok, payload if ok else None, "" if ok else payload)
    finally:  # Ctrl-C or the caller stopped early: stop what is still running
        for process, _ in running.values():
            process.terminate()
            process.join()


def _check_reachable(address: str | None, timeout_s: float = 3.0) -> None:
    """Refuse at once a ``HOST:PORT`` (or ``ray://HOST:PORT``) nobody answers on; Ray itself
    retries for about 20 s and prints its C++ log meanwhile."""
    match = re.fullmatch(r"(?:ray://)?\[?([^\]]+?)\]?:(\d+)", address or "")
    if match is None:
        return
    try:
        socket.create_connection((match[1], int(match[2])), timeout=timeout_s).close()
    except OSError as exc:
        raise BatchError(
            f"cannot reach the Ray cluster at {address} ({exc.strerror or exc}); "
            "start it with 'ray start --head' or check --ray-address"
        ) from None


def run_ray(
    fn: Callable[[str], Any],
    items: Sequence[str],
    address: str | None = None,
    num_cpus: int | None = None,
) -> Iterator[TaskOutcome]:
    """Tasks on a Ray cluster at ``address`` (``None``: a local Ray with ``num_cpus``)."""
    _check_reachable(address)
    try:
        import ray
    except ImportError:
        raise BatchError(
            "--executor ray needs Ray: pip install -e '.[cluster]' (or use --executor local)"
        ) from None
    started_here = not ray.is_initialized()
    try:
        if started_here:
            ray.init(
                address=address,
                num_cpus=None if address else num_cpus,
                include_dashboard=False,
                log_to_driver=False,
                configure_logging=False,
            )
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise BatchError(
            f"cannot reach the Ray cluster at {address or 'local'}: {exc}; "
            f"start it with 'ray start --head' or check --ray-address"
        ) from None
    remote = ray.remote(num_cpus=1, max_retries=0)(_call)
    refs = {remote.remote(fn, item): item for item in items}
    try:
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for ref in done:
                item = refs.pop(ref)
                try:
                    ok, payload = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    ok, payload = False, str(exc).strip().splitlines()[0]
                yield TaskOutcome(item, ok, payload if ok else None, "" if ok else payload)
    finally:
        for ref in refs:
            ray.cancel(ref, force=True)
        if started_here:
            ray.shutdown()


def run_tasks(
    fn: Callable[[str], Any],
    items: Sequence[str],
    executor: str = "local",
    workers: int | None = None,
    ray_address: str | None = None,
) -> Iterator[TaskOutcome]:
    """One task ``fn(item)`` per item on the chosen executor; outcomes as they finish.
    ``fn`` must be picklable (a module-level function or a dataclass instance with __call__)."""
    if executor == "local":
        return run_local(fn, items, workers)
    if executor == "ray":
        return run_ray(fn, items, ray_address, workers)
    raise BatchError(f"unknown executor {executor!r}; choose one of {', '.join(EXECUTORS)}")
