"""Options and summary shared by the commands that run one task per session."""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from vbfe.batch.executors import EXECUTORS, TaskOutcome, run_tasks
from vbfe.batch.settings import BatchSettings
from vbfe.cli.common import progress
from vbfe.common.errors import BatchError


def add_batch_options(parser: argparse.ArgumentParser) -> None:
    """``--executor`` and ``--ray-address`` (with several sessions, ``--overwrite`` redoes
    sessions whose outputs are current and replaces stale ones)."""
    group = parser.add_argument_group("many sessions (a list of files or a manifest CSV)")
    group.add_argument(
        "--executor",
        choices=EXECUTORS,
        default=None,
        help="local: a process per session on this machine (default); "
        "ray: tasks on a Ray cluster (pip install -e '.[cluster]')",
    )
    group.add_argument(
        "--ray-address",
        default=None,
        metavar="HOST:PORT",
        help="Ray cluster to join (default: [batch] ray_address, else a local Ray)",
    )


def batch_settings(args: argparse.Namespace, settings: BatchSettings) -> tuple[str, str | None]:
    """The executor and Ray address: command-line options over the ``[batch]`` table."""
    return args.executor or settings.executor, args.ray_address or settings.ray_address or None


def run_batch(
    task: Callable[[str], Any],
    sessions: Sequence[Path],
    executor: str,
    workers: int | None,
    ray_address: str | None,
    desc: str,
    describe: Callable[[dict[str, Any]], str],
) -> list[TaskOutcome]:
    """Run ``task`` on every session with a progress bar; print one line per session and
    raise :class:`BatchError` naming the failed ones after all have run."""
    missing = [str(s) for s in sessions if not Path(s).is_file()]
    if missing:
        raise BatchError(f"session file(s) not found: {', '.join(missing)}")
    unique: dict[Path, Path] = {}  # a session listed twice is done once
    for session in sessions:
        unique.setdefault(Path(session).resolve(), session)
    sessions = list(unique.values())
    outcomes = []
    with progress(total=len(sessions), desc=desc, unit="session") as bar:
        for outcome in run_tasks(
            task,
            [str(s) for s in sessions],
            executor,
            workers or min(len(sessions), os.cpu_count() or 1),
            ray_address,
        ):
            outcomes.append(outcome)
            bar.update(1)
    for o in sorted(outcomes, key=lambda o: o.item):
        print(f"{o.item}: " + (describe(o.value) if o.ok else f"FAILED: {o.error}"))
    failed = [o for o in outcomes if not o.ok]
    print(f"{len(outcomes) - len(failed)} of {len(outcomes)} sessions done on {executor}")
    if failed:
        raise BatchError(
            f"{len(failed)} of {len(outcomes)} sessions failed: "
            + ", ".join(Path(o.item).name for o in failed)
            + " (reasons above)"
        )
    return outcomes
