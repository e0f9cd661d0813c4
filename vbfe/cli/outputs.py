"""The one check every command runs on its outputs before doing any work.

An output never replaces an existing file unless the user passed ``--overwrite``, and never
replaces one of the command's own inputs, even with ``--overwrite``. Commands then write each
output under a temporary name and rename it when complete.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterable
from pathlib import Path

from vbfe.errors import VbfeError


class OutputError(VbfeError):
    """An output path would overwrite data, or cannot be written."""


def add_overwrite_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--overwrite`` (replace existing output files)."""
    parser.add_argument("--overwrite", action="store_true",
                        help="replace existing output files (never the command's own inputs)")


def add_session_output_options(parser: argparse.ArgumentParser, suffix: str, what: str,
                               clouds_help: str) -> None:
    """``SESSION.h5``, ``-o/--out`` (default: the session's name with ``suffix`` beside it),
    ``--clouds X.clouds.h5`` and ``--overwrite``: a command that turns one session into one
    file; :func:`session_and_output` reads them back, checked."""
    parser.add_argument("session", metavar="SESSION.h5")
    parser.add_argument("-o", "--out", type=Path, default=None, metavar=f"OUT{suffix}",
                        help=f"{what} (default: SESSION{suffix} beside the session)")
    parser.add_argument("--clouds", type=Path, default=None, metavar="X.clouds.h5",
                        help=clouds_help)
    add_overwrite_option(parser)


def session_and_output(args: argparse.Namespace, suffix: str) -> tuple[Path, Path]:
    """The session and the output of :func:`add_session_output_options`, after
    :func:`check_outputs` (the output is neither the session nor the clouds file)."""
    session = Path(args.session)
    out = args.out or session.with_suffix(suffix)
    check_outputs([out], [session, args.clouds], args.overwrite)
    return session, out


def _same_file(a: Path, b: Path) -> bool:
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return a.resolve() == b.resolve()


def check_outputs(outputs: Iterable[str | Path | None], inputs: Iterable[str | Path | None] = (),
                  overwrite: bool = False, directories: Iterable[str | Path | None] = ()) -> None:
    """Refuse, naming the path, an output that is an input, or that exists without
    ``overwrite``, a folder given for a file or a file for a folder, or a file whose folder is
    missing. ``directories`` are output folders: they may exist when empty (or with
    ``overwrite``) and are created by the command."""
    sources = [Path(p) for p in inputs if p is not None]
    for path, is_dir in [(Path(p), False) for p in outputs if p is not None] + \
                        [(Path(p), True) for p in directories if p is not None]:
        for source in sources:
            if _same_file(path, source):
                raise OutputError(f"output {path} is also an input of this command ({source}); "
                                  "choose another output name")
        if is_dir:
            if path.exists() and not path.is_dir():
                raise OutputError(f"output folder {path} is a file; choose another folder")
            parent = next((p for p in path.parents if p.exists()), Path("."))
            if not parent.is_dir():
                raise OutputError(f"output folder {path}: {parent} is a file, not a folder")
            if path.is_dir() and any(path.iterdir()) and not overwrite:
                raise OutputError(f"output folder {path} is not empty; pass --overwrite to write "
                                  "into it anyway or choose a new folder")
            continue
        if path.is_dir():
            raise OutputError(f"output {path} is a folder; give a file name")
        if not path.parent.is_dir():
            raise OutputError(f"output {path}: folder {path.parent} does not exist; create it "
                              "first")
        if path.exists() and not overwrite:
            raise OutputError(f"{path} already exists; pass --overwrite to replace it or choose a "
                              "new name")
