"""`vbfe rig show` / `vbfe rig init`: the effective rig settings and where each came from; a
starting rig file from the devices found."""

from __future__ import annotations

import argparse

from vbfe.cli.common import add_config_option, progress, rig_from
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.common.rig_discovery import LOCAL_NAME


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `rig` subcommand and its `show` and `init`."""
    parser = sub.add_parser("rig", help="show the rig settings in effect, or write a rig file")
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    show = actions.add_parser(
        "show",
        help="print the effective settings as TOML, each with where it came from "
        "(default, or the rig file and how it was found)",
    )
    add_config_option(show)
    show.set_defaults(func=run_show)
    init = actions.add_parser(
        "init", help="write a starting rig file for the devices `vbfe devices` finds"
    )
    init.add_argument(
        "output",
        nargs="?",
        default=LOCAL_NAME,
        metavar="RIG.toml",
        help=f"where to write it (default: ./{LOCAL_NAME}, which every command here finds)",
    )
    add_overwrite_option(init)
    init.set_defaults(func=run_init)


def run_show(args: argparse.Namespace) -> int:
    """Print the settings (the banner, printed first by the entry point, says which file)."""
    from vbfe.rig_config import shown

    print(shown(rig_from(args)))
    return 0


def run_init(args: argparse.Namespace) -> int:
    """Probe the devices, write the rig file (refused over an existing one without
    --overwrite), check it as every command will."""
    import tomlkit

    from vbfe.common.files import write_bytes_atomic
    from vbfe.drivers.devices_list import list_devices
    from vbfe.drivers.rig_template import starting_rig
    from vbfe.rig_config import check_file

    check_outputs([args.output], [], args.overwrite)
    with progress(total=3, desc="probing", unit="family") as bar:
        inventory = list_devices(on_step=lambda family: bar.update(1))
    text, notes = starting_rig(inventory)
    check_file(tomlkit.parse(text).unwrap())
    write_bytes_atomic(args.output, text)
    print("\n".join(notes))
    print(f"wrote {args.output}; `vbfe rig show` prints what commands will use")
    return 0
