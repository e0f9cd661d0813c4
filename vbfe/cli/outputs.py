"""The commands' output options (``--overwrite``, ``-o/--out``) and the one check every command
runs on its outputs before doing any work (:func:`vbfe.batch.inputs.check_outputs`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vbfe.batch.inputs import check_outputs, command_inputs
from vbfe.common.errors import OutputError

__all__ = ["OutputError", "add_overwrite_option", "check_outputs", "command_inputs"]


def add_overwrite_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--overwrite`` (replace existing output files)."""
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace existing output files (never the command's own inputs, "
        "never a session by another kind of file)",
    )


def add_session_output_options(
    parser: argparse.ArgumentParser, suffix: str, what: str, clouds_help: str
) -> None:
    """``SESSION.h5``, ``-o/--out`` (default: the session's name with ``suffix`` beside it),
    ``--clouds X.clouds.h5`` and ``--overwrite``: a command that turns one session into one
    file; :func:`session_and_output` reads them back, checked."""
    parser.add_argument("session", metavar="SESSION.h5", help="the session")
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
