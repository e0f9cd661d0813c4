"""Worker processes of the estimate stage: spawned, one torch and OpenCV thread each.

A spawned worker imports torch before it does anything, about :data:`WORKER_START_S`: work
goes to workers only when it is expected to take longer than that (fold refits: twice as
long). Session preparation (``dataset.py``) maps sessions over a pool; training
(``training.py``) hands its fold refits to a :class:`BackgroundPool` and goes on fitting
beside them.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from types import TracebackType
from typing import Any, Generic, TypeVar

import cv2
import torch

from vbfe.common.signals import kill_workers, stop_pool_on_signals

# a worker process's start: spawned, it imports torch and the estimate stage (3.9 s measured)
WORKER_START_S = 4.0

T = TypeVar("T")

log = logging.getLogger(__name__)


def single_threaded() -> None:
    """A worker's start: one thread each (the workers share the cores)."""
    cv2.setNumThreads(1)
    torch.set_num_threads(1)


def spawn_pool(workers: int) -> ProcessPoolExecutor:
    """``workers`` spawned processes, one thread each."""
    return ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=single_threaded,
    )


class Task(Generic[T]):
    """A task handed to a :class:`BackgroundPool`: running in a worker, or waiting to run."""

    def __init__(self, call: Callable[..., T], args: tuple[Any, ...]) -> None:
        self.call, self.args = call, args
        self.future: Future[T] | None = None  # set once handed to the workers


class BackgroundPool:
    """Tasks run beside the caller's own work: in worker processes, started on the first task
    worth them, or, for a task not worth them, here when its result is asked for (or in the
    workers, if they started for other tasks meanwhile: their start is paid). A task must not
    depend on where it ran (a fold refit runs torch on one thread either way). Waiting for a
    result, Ctrl-C and SIGTERM stop the workers at once; leaving the block on an exception
    kills them."""

    def __init__(self, what: str, at_least: int = 1) -> None:
        """``what`` the tasks are, for the log; one worker per core, at least ``at_least``
        (tasks of equal size that many: three on two workers take two rounds, on three a
        third less); none on one core."""
        self._what = what
        cores = os.cpu_count() or 1
        self._workers = max(cores, at_least) if cores >= 2 else 1
        self._pool: ProcessPoolExecutor | None = None
        self._waiting: list[Task[Any]] = []

    def worth_workers(self, expected_cpu_s: float) -> bool:
        """Whether tasks expected to cost ``expected_cpu_s`` CPU seconds are worth the workers'
        start: two cores or more, and more than twice what the workers take to start (they
        compete with the caller's own work: fold refits of 15 CPU s ran 7 s longer in three
        workers than here)."""
        return self._workers >= 2 and expected_cpu_s > 2 * self._workers * WORKER_START_S

    def submit(self, in_worker: bool, call: Callable[..., T], *args: Any) -> Task[T]:
        """``call(*args)``: in a worker with ``in_worker`` (see :meth:`worth_workers`), else
        when its result is asked for, or by the workers if they start before that."""
        task = Task(call, args)
        self._waiting.append(task)
        if in_worker:
            if self._pool is None:
                log.info("%s in %d worker processes", self._what, self._workers)
                self._pool = spawn_pool(self._workers)
            pool = self._pool
            for waiting in [task, *self._waiting[:-1]]:  # this one first: it is worth them
                waiting.future = pool.submit(waiting.call, *waiting.args)
            self._waiting.clear()
        return task

    def result(self, task: Task[T]) -> T:
        """The task's result: run here if it is still waiting, else waited for."""
        if task.future is None:
            self._waiting.remove(task)
            task.future = Future()
            task.future.set_result(task.call(*task.args))
        if self._pool is None or task.future.done():
            return task.future.result()
        with stop_pool_on_signals(self._pool):
            return task.future.result()

    def __enter__(self) -> BackgroundPool:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        if self._pool is None:
            return
        if error is not None:  # Ctrl-C in the caller's own work: the workers' tasks are moot
            kill_workers(self._pool)
        self._pool.shutdown(wait=error is None, cancel_futures=True)
