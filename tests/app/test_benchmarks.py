"""Every benchmark runs at its smallest setting (``--smoke``), as users run it
(``python -m benchmarks.NAME``), so that none stops working unseen; the figures are the
benchmarks' own business (their defaults), not checked here."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from tests import paths

ROOT = paths.REPO
BENCHMARKS = sorted(p.stem for p in (ROOT / "benchmarks").glob("bench_*.py"))


@pytest.mark.slow
@pytest.mark.timeout(1800)  # a hang guard: bench_selection's smoke runs a quick demo of its own
@pytest.mark.parametrize("name", BENCHMARKS)
def test_benchmark_runs_at_its_smallest_setting(name):
    # its temporary files in a folder of its own, where it must leave no smoke recordings (a
    # quick demo's, left behind by each run, filled CI's disk); a short path: Ray's sockets
    # live there, and a socket's path has at most 107 bytes
    tmp = Path(tempfile.mkdtemp(prefix="vb"))
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "MPLBACKEND": "Agg", "TMPDIR": str(tmp)}
    try:
        run = subprocess.run(
            [sys.executable, "-m", f"benchmarks.{name}", "--smoke"],
            capture_output=True,
            text=True,
            cwd=ROOT,
            env=env,
            timeout=1700,
        )
        left = list(tmp.glob("vbfe-smoke-*"))  # torch's and Ray's files may stay
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    printed = run.stdout.splitlines()
    assert printed and any(char.isdigit() for line in printed for char in line), run.stdout
    assert not left, f"smoke recordings left behind: {left}"
