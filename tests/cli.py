"""The `vbfe` command as tests run it: in a subprocess (what users run) or, cheaper, its entry
point in this process (same parser and error printing, no start-up)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from vbfe.cli.main import main


def vbfe(
    *args: object, cwd: str | Path | None = None, timeout: float = 600
) -> subprocess.CompletedProcess[str]:
    """The real CLI in a subprocess, its output captured as text."""
    return subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=timeout,
    )


def vbfe_here(capsys: pytest.CaptureFixture[str], *args: str) -> subprocess.CompletedProcess[str]:
    """The CLI's entry point in this process, with what it printed (earlier output dropped)."""
    capsys.readouterr()
    code = main(list(args))
    out = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, out.out, out.err)
