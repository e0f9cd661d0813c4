"""`vbfe console`: one window for the lab operator (rig, live, record, calibrate, sync, review)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vbfe.cli.common import add_config_option, positive, rig_from
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.common.errors import VbfeError
from vbfe.console import TAB_NAMES


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `console` subcommand."""
    parser = sub.add_parser(
        "console",
        help="one window: rig, live view and estimate, record, calibrate, sync, review",
        description="A Qt window over the rig: device states, live images and force, "
        "recordings with markers and remote control, calibration views and calibration, "
        "the sync protocol, the last session's report. Headless with --duration "
        "(QT_QPA_PLATFORM=offscreen): record (--record), write screenshots, exit.",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("."),
        metavar="DIR",
        help="default folder of sessions, views and calibrations (default: here)",
    )
    parser.add_argument(
        "--calib",
        metavar="CALIB.yaml",
        default=None,
        help="stored calibration: kept with recordings, the GO/NO-GO reference, and "
        "the live estimate's (with --model)",
    )
    parser.add_argument(
        "--model", metavar="MODEL.pt", default=None, help="estimate force live (needs --calib)"
    )
    parser.add_argument(
        "--record", type=Path, default=None, metavar="SESSION.h5", help="record at once"
    )
    parser.add_argument(
        "--duration",
        type=positive(float),
        default=None,
        metavar="S",
        help="headless run: record (or show live) this long, write the screenshots, exit",
    )
    parser.add_argument(
        "--screenshot", type=Path, default=None, metavar="PNG", help="the Live tab, at the end"
    )
    parser.add_argument(
        "--screenshot-dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="one PNG per tab (rig.png, live.png, ...), at the end",
    )
    parser.add_argument(
        "--remote",
        type=int,
        default=None,
        metavar="PORT",
        help="serve `vbfe record --remote`'s commands on this TCP port (0: any free port)",
    )
    parser.add_argument(
        "--remote-bind",
        default="127.0.0.1",
        metavar="ADDRESS",
        help="address the remote-control port listens on (default: localhost only; 0.0.0.0 "
        "for every interface)",
    )
    add_overwrite_option(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Open the console; in a headless run, exit when done (2 when an error was shown)."""
    from vbfe.calib import Calibration, load_calibration
    from vbfe.console.app import Headless, run_console
    from vbfe.console.station import Station
    from vbfe.console.window import ConsoleOptions

    if args.duration is None and (args.screenshot or args.screenshot_dir):
        raise VbfeError("--screenshot and --screenshot-dir need a headless run: add --duration S")
    if args.model and not args.calib:
        raise VbfeError("--model needs the calibration it estimates with: add --calib CALIB.yaml")
    check_outputs([args.record], [args.calib, args.model], writes="session")  # a new file
    shots = [args.screenshot]
    if args.screenshot_dir is not None:
        args.screenshot_dir.mkdir(parents=True, exist_ok=True)
        shots += [args.screenshot_dir / f"{name.lower()}.png" for name in TAB_NAMES]
    check_outputs(shots, [args.calib, args.model], args.overwrite)
    if not args.out.is_dir():
        raise VbfeError(f"--out {args.out}: no such folder; make it first")
    config = rig_from(args)
    calibration: Calibration | None = load_calibration(args.calib) if args.calib else None
    estimator = None
    if args.model and calibration is not None:  # --model without --calib is refused above
        from vbfe.estimate import load_model
        from vbfe.live.run import live_estimator

        estimator = live_estimator(config, load_model(args.model), calibration)
    station = Station(config, calibration, args.calib or "the calibration", estimator, args.model)
    station.model_path = Path(args.model) if args.model else None
    headless = (
        Headless(args.duration, args.screenshot, args.screenshot_dir)
        if args.duration is not None
        else None
    )
    options = ConsoleOptions(
        args.out,
        Path(args.calib) if args.calib else None,
        args.overwrite,
        headless is None,
        config.source.path,  # what the operator settles is kept there
    )
    code, _ = run_console(station, options, headless, args.record, args.remote, args.remote_bind)
    finished = station.last_session
    if finished is not None and code == 0:
        print(f"recorded {finished}")
    return code
