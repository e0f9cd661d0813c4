"""`vbfe view`: replay a session with a time slider, or watch the devices live."""

from __future__ import annotations

import argparse

from vbfe.cli.common import add_config_option, rig_from
from vbfe.common.errors import VbfeError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `view` subcommand."""
    parser = sub.add_parser(
        "view", help="replay a session (images, force, drops) or watch the devices live (--live)"
    )
    parser.add_argument(
        "session", metavar="SESSION.h5", nargs="?", default=None, help="the session to replay"
    )
    parser.add_argument("--live", action="store_true", help="show the rig's devices live")
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the viewer until its window closes."""
    from vbfe.acquire.viewer import view_live, view_session  # Qt loads only for this command

    if args.live:
        return view_live(rig_from(args))
    if args.session is None:
        raise VbfeError("give a SESSION.h5 to replay, or --live")
    return view_session(args.session)
