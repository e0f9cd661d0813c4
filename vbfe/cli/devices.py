"""`vbfe devices`: list the cameras, CAN interfaces and serial ports this machine has."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict

from vbfe.cli.common import progress
from vbfe.drivers.devices_list import format_inventory, list_devices


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `devices` subcommand."""
    parser = sub.add_parser(
        "devices",
        help="list cameras, CAN interfaces and serial ports",
        description="List V4L2 cameras (pixel formats, frame sizes and "
        "rates, controls), CAN interfaces and serial ports; says plainly "
        "when none are found.",
    )
    parser.add_argument("--json", action="store_true", help="print the list as JSON")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Probe the machine and print what was found (exit 0 also when nothing is)."""
    with progress(total=3, desc="probing", unit="family") as bar:
        inventory = list_devices(on_step=lambda family: bar.update(1))
    print(json.dumps(asdict(inventory), indent=2) if args.json else format_inventory(inventory))
    return 0
