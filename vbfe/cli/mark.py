"""`vbfe mark`: put an event mark into the running recording (through its remote-control port)."""

from __future__ import annotations

import argparse

from vbfe.acquire.recording.remote import DEFAULT_PORT, send_command
from vbfe.common.errors import VbfeError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `mark` subcommand."""
    parser = sub.add_parser(
        "mark",
        help="mark an event in the running recording (`vbfe record --remote PORT`)",
        description="Sends the text to a recorder started with `vbfe record --remote PORT`; it "
        "is stored in the session's event list at the host time the recorder receives it.",
    )
    parser.add_argument("text", help='what happened, e.g. "grasp begins"')
    parser.add_argument(
        "--port",
        type=int,
        default=DEFAULT_PORT,
        help=f"the recorder's remote-control port (default {DEFAULT_PORT})",
    )
    parser.add_argument("--host", default="127.0.0.1", help="the recorder's host")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Send the mark and report the recorder's answer."""
    text = " ".join(args.text.split())
    if not text:
        raise VbfeError('the mark\'s text is empty; say what happened, e.g. "grasp begins"')
    reply = send_command(f"mark {text}", args.port, args.host, timeout_s=5.0)
    if reply != "OK":
        raise VbfeError(
            f"the recorder on {args.host}:{args.port} refused the mark: "
            f"{reply.removeprefix('ERROR ')}"
        )
    print(f"marked: {text}")
    return 0
