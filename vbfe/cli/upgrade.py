"""`vbfe upgrade`: rewrite a session (or cloud file) of an earlier vbfe into the portable format."""

from __future__ import annotations

import argparse
from pathlib import Path

from vbfe.acquire.session.layout import COMPRESSIONS, DEFAULT_COMPRESSION, IMAGE_CODECS
from vbfe.acquire.session.portable import upgrade_file
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.common.errors import OutputError
from vbfe.common.files import is_session


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `upgrade` subcommand."""
    parser = sub.add_parser(
        "upgrade",
        help="rewrite a session into the portable format (MATLAB, HDFView, h5dump read it)",
        description="Copies every dataset and attribute of a session or cloud file written by "
        "an earlier vbfe into HDF5 1.10's file format, raw camera images under --compression, "
        "and compares the copy value by value with the original before it is renamed into "
        "place. Without -o the file is replaced in place, which needs --overwrite.",
    )
    parser.add_argument("session", metavar="SESSION.h5", help="the file to upgrade")
    parser.add_argument(
        "-o",
        "--output",
        metavar="OUT.h5",
        default=None,
        help="write the upgraded copy here (default: replace SESSION.h5, with --overwrite)",
    )
    parser.add_argument(
        "--compression",
        choices=COMPRESSIONS,
        default=DEFAULT_COMPRESSION,
        help=f"camera image storage of the copy (default {DEFAULT_COMPRESSION}: "
        f"{IMAGE_CODECS[DEFAULT_COMPRESSION].readers})",
    )
    add_overwrite_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Upgrade and say where the copy went."""
    source = Path(args.session)
    if not source.is_file():
        raise OutputError(f"{source} does not exist; give a session file")
    out = Path(args.output) if args.output else source
    if args.output:
        check_outputs([out], [source], args.overwrite, writes="session")
    elif not args.overwrite:
        raise OutputError(
            f"upgrading {source} in place replaces it: pass --overwrite, or -o OUT.h5 for a copy"
        )
    images = f", camera images {args.compression}" if is_session(source) else ""
    upgrade_file(source, out, args.compression, overwrite=args.overwrite)
    where = "in place" if out == source else f"into {out}"
    print(f"upgraded {source} {where}: HDF5 1.10 file format{images}")
    return 0
