"""`vbfe report`: one self-contained HTML page on a session's quality."""

from __future__ import annotations

import argparse

from vbfe.cli.outputs import add_session_output_options, session_and_output


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `report` subcommand."""
    parser = sub.add_parser(
        "report",
        help="write a self-contained HTML page on a session's quality",
        description="One HTML page (images inline, nothing else to copy) with the force "
        "trace and its gaps, frame thumbnails, per-stream rate and jitter, clock fits, "
        "projector events, the sync verdict, the calibration, reconstruction density (from "
        "SESSION.clouds.h5 when present) and live estimates against the trocar.",
    )
    add_session_output_options(
        parser, ".html", "output page", "clouds file (default: SESSION.clouds.h5 when it exists)"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the page and print its path."""
    from vbfe.session_report import write_session_report

    session, out = session_and_output(args, ".html")
    print(f"wrote {write_session_report(session, out, args.clouds)}")
    return 0
