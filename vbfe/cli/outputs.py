"""The one check every command runs on its outputs before doing any work (see vbfe.common.files).

The inputs a command names are expanded to everything it reads: the sessions a manifest lists
and the ``X.clouds.h5`` sidecar of every session, so none of them can be an output.
"""

from __future__ import annotations

import argparse
import glob
from collections.abc import Iterable
from pathlib import Path

from vbfe.common.errors import OutputError
from vbfe.common.files import Writes
from vbfe.common.files import check_outputs as _check

__all__ = ["OutputError", "add_overwrite_option", "check_outputs", "command_inputs"]


def add_overwrite_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--overwrite`` (replace existing output files)."""
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace existing output files (never the command's own inputs, "
        "never a session by another kind of file)",
    )


def command_inputs(inputs: Iterable[str | Path | None], sidecars: bool = True) -> list[Path]:
    """Every file the inputs stand for: themselves (or the files a glob matches), the sessions
    of manifests (``*.csv`` with a ``path`` column) and (with ``sidecars``) the clouds sidecar
    of every session."""
    from vbfe.batch.manifest import MANIFEST_SUFFIX, read_manifest
    from vbfe.common.errors import BatchError
    from vbfe.recon.clouds import sidecar_path

    out: list[Path] = []
    for item in (Path(p) for p in inputs if p is not None):
        if not item.exists() and glob.has_magic(str(item)):  # a quoted glob of images
            out.extend(Path(p) for p in glob.glob(str(item)))
        out.append(item)
        listed: list[Path] = []
        if item.suffix == MANIFEST_SUFFIX and item.is_file():
            try:
                listed = read_manifest(item)
            except BatchError:  # another kind of CSV (forces, frame times)
                pass
        for path in (item, *listed):
            if path is not item:
                out.append(path)
            if (
                sidecars
                and path.suffix.lower() in (".h5", ".hdf5")
                and not path.name.endswith(".clouds.h5")
            ):
                out.append(sidecar_path(path))
    return out


def add_session_output_options(
    parser: argparse.ArgumentParser, suffix: str, what: str, clouds_help: str
) -> None:
    """``SESSION.h5``, ``-o/--out`` (default: the session's name with ``suffix`` beside it),
    ``--clouds X.clouds.h5`` and ``--overwrite``: a command that turns one session into one
    file; :func:`session_and_output` reads them back, checked."""
    parser.add_argument("session", metavar="SESSION.h5")
    parser.add_argument(
        "-o",
        "--out",
        type=Path,
        default=None,
        metavar=f"OUT{suffix}",
        help=f"{what} (default: SESSION{suffix} beside the session)",
    )
    parser.add_argument(
        "--clouds", type=Path, default=None, metavar="X.clouds.h5", help=clouds_help
    )
    add_overwrite_option(parser)


def session_and_output(args: argparse.Namespace, suffix: str) -> tuple[Path, Path]:
    """The session and the output of :func:`add_session_output_options`, after
    :func:`check_outputs` (the output is neither the session nor the clouds file)."""
    session = Path(args.session)
    out = args.out or session.with_suffix(suffix)
    check_outputs([out], [session, args.clouds], args.overwrite)
    return session, out


def check_outputs(
    outputs: Iterable[str | Path | None],
    inputs: Iterable[str | Path | None] = (),
    overwrite: bool = False,
    directories: Iterable[str | Path | None] = (),
    writes: Writes = "file",
    sidecars: bool = True,
) -> None:
    """:func:`vbfe.common.files.check_outputs` against everything the inputs stand for (without the
    sessions' sidecars when ``sidecars`` is false: a command that writes them)."""
    _check(outputs, command_inputs(inputs, sidecars), overwrite, directories, writes)
