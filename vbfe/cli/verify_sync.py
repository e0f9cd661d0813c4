"""`vbfe verify-sync`: measure the image/force offset of a session and judge it."""

from __future__ import annotations

import argparse
from pathlib import Path

from vbfe.acquire.sync_check import FAIL, PASS, SyncLimits, verify_sync
from vbfe.acquire.sync_protocol import ProtocolSettings
from vbfe.cli.common import add_config_option, config_from


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `verify-sync` subcommand."""
    parser = sub.add_parser("verify-sync", help="estimate the image-force time offset, clock "
                            "drift and drops of a session; PASS/FAIL against the rig's limits "
                            "(exit 0/1; 3: inconclusive, record --protocol sync)")
    parser.add_argument("session", metavar="SESSION.h5")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="plot of the offset measurement (default: SESSION.sync.png)")
    parser.add_argument("--apply", action="store_true",
                        help="store the measured offset as a frame-time correction and print "
                             "the rig config line that applies it to new sessions")
    parser.add_argument("--no-store", action="store_true",
                        help="do not write the results into the session")
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the report; exit code 0 PASS, 1 FAIL, 3 INCONCLUSIVE."""
    plot = args.plot or str(Path(args.session).with_suffix(".sync.png"))
    config = config_from(args)
    report = verify_sync(args.session, SyncLimits.from_config(config), plot_path=plot,
                         store=not args.no_store, apply_correction=args.apply,
                         settings=ProtocolSettings.from_config(config))
    print(report.text())
    if args.apply:
        print(f"rig config  add to [record] of your rig.toml so new sessions are corrected: "
              f"{report.config_suggestion()}")
    return {PASS: 0, FAIL: 1}.get(report.verdict, 3)
