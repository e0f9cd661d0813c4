"""`vbfe verify-sync`: measure the image/force offset of a session and judge it."""

from __future__ import annotations

import argparse
from pathlib import Path

from vbfe.acquire.sync_check import SyncLimits, verify_sync
from vbfe.cli.common import add_config_option, config_from
from vbfe.cli.outputs import add_overwrite_option, check_outputs


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `verify-sync` subcommand."""
    parser = sub.add_parser("verify-sync", help="estimate the image-force time offset, clock "
                            "drift and drops of a session; pass/fail against the rig's limits")
    parser.add_argument("session", metavar="SESSION.h5")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="plot of the offset measurement (default: SESSION.sync.png)")
    parser.add_argument("--apply", action="store_true",
                        help="store the measured offset as a frame-time correction")
    parser.add_argument("--no-store", action="store_true",
                        help="do not write the results into the session")
    add_overwrite_option(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the report; exit code 1 when the verdict is FAIL."""
    plot = args.plot or str(Path(args.session).with_suffix(".sync.png"))
    # the default plot is this command's own product and is refreshed on every run
    check_outputs([plot], [args.session], overwrite=args.overwrite or args.plot is None)
    report = verify_sync(args.session, SyncLimits.from_config(config_from(args)), plot_path=plot,
                         store=not args.no_store, apply_correction=args.apply)
    print(report.text())
    return 0 if report.passed else 1
