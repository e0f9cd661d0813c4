"""Pieces shared by the subcommands: the --config option and progress bars."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from tqdm import tqdm

from vbfe.config import load_config
from vbfe.errors import VbfeError


def add_config_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--config rig.toml`` (defaults run the simulated bench)."""
    parser.add_argument("--config", metavar="RIG.toml", default=None,
                        help="rig configuration (default: the simulated bench)")


def config_from(args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """The rig configuration the user chose."""
    return load_config(getattr(args, "config", None))


def check_output_path(path: str | Path, what: str, folder: bool = False) -> Path:
    """Fail before any work when ``path`` cannot become the file (or ``folder``) to write:
    a folder given for a file, a file given for a folder, or a parent folder that is missing."""
    path = Path(path)
    if folder:
        if path.exists() and not path.is_dir():
            raise VbfeError(f"{what} {path} is a file, not a folder; give a folder to write into")
        parent = next((p for p in path.parents if p.exists()), Path("."))
        if not parent.is_dir():
            raise VbfeError(f"{what} {path}: {parent} is a file, not a folder")
        return path
    if path.is_dir():
        raise VbfeError(f"{what} {path} is a folder; give a file name to write")
    if not path.parent.is_dir():
        raise VbfeError(f"{what} {path}: folder {path.parent} does not exist; create it first")
    return path


def progress(total: int | None = None, desc: str = "", unit: str = "it") -> tqdm:
    """A progress bar on stderr; quiet when stderr is not a terminal and CI is set."""
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True,
                mininterval=0.5)


STAGE_UNITS = {"sessions": "session", "epochs": "epoch", "predict": "session"}


class StageProgress:
    """One progress bar per stage of a ``(stage, done, total)`` progress callback."""

    def __init__(self) -> None:
        self._stage: str | None = None
        self._bar: tqdm | None = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage != self._stage:
            self.close()
            self._stage = stage
            self._bar = progress(total=total, desc=stage, unit=STAGE_UNITS.get(stage, "it"))
        assert self._bar is not None
        self._bar.update(done - self._bar.n)

    def close(self) -> None:
        """Close the current bar."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
