"""Run a benchmark and keep what it printed, with when, where and under what load.

    python -m benchmarks.logbook bench_sync [ARGS...]

runs ``python -m benchmarks.bench_sync ARGS`` (its output shown as it comes) and, when it
exits 0, writes ``benchmarks/runs/bench_sync/<UTC time>.json``: the command, the commit, the
machine (CPU model, cores, Python, torch), the load average sampled every 5 s while it ran,
the wall time and the printed lines. Nothing is overwritten: each run is a new file. The
manual's benchmark page (docs/benchmarks/index.md) is generated from the latest run of each
benchmark (tools/docs_reference.py), so its figures are what a benchmark printed, never
retyped.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import threading
import time
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
RUNS = ROOT / "benchmarks" / "runs"
_LOAD_EVERY_S = 5.0


def machine() -> dict[str, Any]:
    """What the figures were measured on."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        torch_version = metadata.version("torch")
    except metadata.PackageNotFoundError:
        torch_version = "not installed"
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "torch": torch_version,
        "system": f"{platform.system()} {platform.release()}",
    }


def commit() -> str:
    """The checked-out commit, ``-dirty`` when the tree has changes."""
    try:
        return subprocess.run(
            ["git", "describe", "--always", "--dirty", "--abbrev=10"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _sample_load(samples: list[float], stop: threading.Event) -> None:
    while True:
        samples.append(os.getloadavg()[0])
        if stop.wait(_LOAD_EVERY_S):
            return


def run(name: str, args: list[str]) -> tuple[int, dict[str, Any]]:
    """Run one benchmark, echoing its output; its exit status and the run's record."""
    command = [sys.executable, "-m", f"benchmarks.{name}", *args]
    started = datetime.now(timezone.utc)
    loads: list[float] = []
    stop = threading.Event()
    sampler = threading.Thread(target=_sample_load, args=(loads, stop), daemon=True)
    sampler.start()
    t0 = time.monotonic()
    lines: list[str] = []
    with subprocess.Popen(
        command, cwd=ROOT, stdout=subprocess.PIPE, text=True, bufsize=1
    ) as process:
        assert process.stdout is not None
        for line in process.stdout:
            sys.stdout.write(line)
            lines.append(line.rstrip("\n"))
    stop.set()
    sampler.join()
    loads.append(os.getloadavg()[0])
    record = {
        "benchmark": name,
        "command": f"python -m benchmarks.{name} {' '.join(args)}".strip(),
        "started_utc": started.strftime("%Y-%m-%d %H:%M UTC"),
        "wall_s": round(time.monotonic() - t0, 1),
        "commit": commit(),
        "machine": machine(),
        "load_average": {"min": min(loads), "max": max(loads)},
        "output": lines,
    }
    return process.returncode, record


def main(argv: list[str] | None = None, runs: Path = RUNS) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    names = sorted(p.stem for p in (ROOT / "benchmarks").glob("bench_*.py"))
    if not argv or argv[0] not in names:
        print(f"usage: python -m benchmarks.logbook NAME [ARGS...]; NAME one of {', '.join(names)}")
        return 2
    name, args = argv[0], argv[1:]
    if "--smoke" in args:
        print("--smoke figures mean nothing: run the benchmark at the settings to keep")
        return 2
    status, record = run(name, args)
    if status != 0:
        print(f"{name} exited {status}: nothing kept")
        return status
    folder = runs / name
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%SZ')}.json"
    with open(path, "x") as out:  # a new file per run
        json.dump(record, out, indent=1)
        out.write("\n")
    print(f"kept in {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
