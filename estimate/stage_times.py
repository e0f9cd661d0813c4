"""Wall and CPU seconds of the stages of a training run (stored in its record, printed by
``benchmarks/bench_train.py``).

CPU seconds are the process's (every thread) plus its finished child processes': on two
busy cores a stage's wall time says how loaded the machine was, its CPU time what it cost.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager

STATUS_SEPARATOR = " · "  # a progress stage "name · status": the bar's name, then its status


def cpu_seconds() -> float:
    """CPU seconds used so far by this process and its waited-for children."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class StageTimes:
    """``{stage: {"wall_s": …, "cpu_s": …}}``, a stage timed twice summed."""

    def __init__(self) -> None:
        self.seconds: dict[str, dict[str, float]] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the body as ``name``."""
        wall, cpu = time.perf_counter(), cpu_seconds()
        try:
            yield
        finally:
            entry = self.seconds.setdefault(name, {"wall_s": 0.0, "cpu_s": 0.0})
            entry["wall_s"] += time.perf_counter() - wall
            entry["cpu_s"] += cpu_seconds() - cpu

    def add(self, seconds: dict[str, dict[str, float]], prefix: str = "") -> None:
        """Add the stages ``seconds`` timed elsewhere (another ``StageTimes``' ``seconds``, a
        worker process's), each as ``prefix + stage``."""
        for stage, entry in seconds.items():
            total = self.seconds.setdefault(prefix + stage, {"wall_s": 0.0, "cpu_s": 0.0})
            total["wall_s"] += entry["wall_s"]
            total["cpu_s"] += entry["cpu_s"]

    @contextmanager
    def parts(self, name: str) -> Iterator[StageTimes]:
        """Time the body as ``name``; the stages timed on the ``StageTimes`` it yields are
        kept as ``name: stage``."""
        inner = StageTimes()
        with self.stage(name):
            yield inner
        self.add(inner.seconds, f"{name}: ")
