"""`vbfe report`: one self-contained HTML page on a session's quality."""

from __future__ import annotations

import argparse
from pathlib import Path

from vbfe.cli.outputs import add_overwrite_option, check_outputs


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `report` subcommand."""
    parser = sub.add_parser(
        "report", help="write a self-contained HTML page on a session's quality",
        description="One HTML page (images inline, nothing else to copy) with the force "
        "trace and its gaps, frame thumbnails, per-stream rate and jitter, clock fits, "
        "projector events, the sync verdict, the calibration, reconstruction density (from "
        "SESSION.clouds.h5 when present) and live estimates against the trocar.")
    parser.add_argument("session", metavar="SESSION.h5")
    parser.add_argument("-o", "--out", type=Path, default=None, metavar="PAGE.html",
                        help="output page (default: SESSION.html beside the session)")
    parser.add_argument("--clouds", type=Path, default=None, metavar="X.clouds.h5",
                        help="clouds file (default: SESSION.clouds.h5 when it exists)")
    add_overwrite_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the page and print its path."""
    from vbfe.session_report import write_session_report

    session = Path(args.session)
    out = args.out or session.with_suffix(".html")
    check_outputs([out], [session, args.clouds], args.overwrite)
    print(f"wrote {write_session_report(session, out, args.clouds)}")
    return 0
