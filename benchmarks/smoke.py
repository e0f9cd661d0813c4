"""``--smoke``: every benchmark's smallest setting (one size, one repeat, the shortest run),
which CI's slow tier runs (tests/app/test_benchmarks.py) so that no benchmark stops working unseen.
Its figures mean nothing; the defaults give the documented ones."""

from __future__ import annotations

import argparse
import atexit
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def parse(
    parser: argparse.ArgumentParser, argv: Sequence[str] | None, **smallest: Any
) -> argparse.Namespace:
    """``parser``'s arguments plus ``--smoke``, which sets each of ``smallest`` (option name
    with underscores: value) over what was given."""
    settings = ", ".join(f"{name}={value}" for name, value in smallest.items())
    parser.add_argument(
        "--smoke", action="store_true", help=f"smallest setting, only to check it runs ({settings})"
    )
    args = parser.parse_args(argv)
    if args.smoke:
        for name, value in smallest.items():
            setattr(args, name, value)
    return args


def scratch() -> Path:
    """A new folder for a smoke run's recordings, removed when the process exits (a quick
    demo's sessions take about a gigabyte: left behind, CI's disk fills)."""
    folder = Path(tempfile.mkdtemp(prefix="vbfe-smoke-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder
