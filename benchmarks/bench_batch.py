"""Batch reconstruction of N small bench sessions: serial, local process pool, local Ray.

Records N short sessions on the simulated bench (with their exact calibration), then
reconstructs all of them three ways in the same run and prints each wall time and its ratio to
the serial run. Run: ``python -m benchmarks.bench_batch [--sessions N] [--seconds S]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import os
import tempfile
import time
from pathlib import Path

from benchmarks import smoke
from vbfe.acquire import record_session
from vbfe.batch.executors import run_tasks
from vbfe.batch.tasks import ReconstructTask
from vbfe.recon import SgbmParams
from vbfe.rig_config import builtin_rig
from vbfe.truth import calibration_from_rig, true_rig


def record_sessions(folder: Path, n: int, seconds: float) -> list[str]:
    """``n`` bench sessions of ``seconds`` at 320×180, 15 fps, one seed each."""
    paths = []
    for seed in range(n):
        config = builtin_rig({"bench": dict(width=320, height=180, fps=15.0, seed=seed)})
        calibration = calibration_from_rig(true_rig(config))
        path = folder / f"s{seed}.h5"
        record_session(
            config, path, duration_s=seconds, calibration_yaml=calibration.to_yaml_text()
        )
        paths.append(str(path))
    return paths


def timed(executor: str, sessions: list[str], workers: int) -> float:
    """Wall time to rebuild every session's clouds on ``executor``."""
    task = ReconstructTask(sgbm=dataclasses.asdict(SgbmParams()), overwrite=True)
    start = time.perf_counter()
    outcomes = list(run_tasks(task, sessions, executor, workers))
    elapsed = time.perf_counter() - start
    failed = [o for o in outcomes if not o.ok]
    if failed:
        raise SystemExit(f"{executor}: {failed[0].item} failed: {failed[0].error}")
    return elapsed


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=2.0)
    args = smoke.parse(parser, argv, sessions=2, seconds=0.5)
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        sessions = record_sessions(Path(tmp), args.sessions, args.seconds)
        serial = timed("local", sessions, 1)
        pool = timed("local", sessions, cores)
        ray_s = timed("ray", sessions, cores) if importlib.util.find_spec("ray") else None
    print(
        f"{args.sessions} sessions of {args.seconds:g} s (320x180, 15 fps), {cores} cores, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    print(f"{'serial (1 process)':<24} {serial:7.1f} s   speed-up 1.00x")
    print(f"{'local pool':<24} {pool:7.1f} s   speed-up {serial / pool:.2f}x")
    if ray_s is None:
        print(f"{'local Ray':<24}   not installed (pip install -e '.[cluster]')")
    else:
        print(f"{'local Ray':<24} {ray_s:7.1f} s   speed-up {serial / ray_s:.2f}x")


if __name__ == "__main__":
    main()
