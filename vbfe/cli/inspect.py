"""`vbfe inspect`: summarize a session file (counts, drops, gaps, clocks; truncated or not)."""

from __future__ import annotations

import argparse

from vbfe.acquire import recover_session
from vbfe.acquire.inspect import inspect_session
from vbfe.cli.common import check_output_path


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `inspect` subcommand."""
    parser = sub.add_parser("inspect", help="summarize a recorded session")
    parser.add_argument("session", metavar="SESSION.h5")
    parser.add_argument("--recover", metavar="OUT.h5", default=None,
                        help="copy an interrupted session into a clean, finalized file")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the summary; exit code 1 when the file was not closed cleanly."""
    if args.recover:
        check_output_path(args.recover, "recovered session")
        recover_session(args.session, args.recover)
        print(f"recovered {args.session} into {args.recover}")
        args.session = args.recover
    summary = inspect_session(args.session)
    print(summary.text())
    return 1 if summary.truncated else 0
