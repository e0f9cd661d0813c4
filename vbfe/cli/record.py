"""`vbfe record`: record stereo video, trocar force and projector events into a session file."""

from __future__ import annotations

import argparse

from vbfe.acquire import RecorderStats, record_session
from vbfe.acquire.layout import COMPRESSIONS
from vbfe.cli.common import add_config_option, config_from, progress
from vbfe.errors import VbfeError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `record` subcommand."""
    parser = sub.add_parser("record", help="record a session (stereo video + force + projector) "
                            "until Ctrl-C or --duration")
    parser.add_argument("output", metavar="SESSION.h5", help="new session file")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after this many seconds of video (default: Ctrl-C)")
    parser.add_argument("--operator", default="", help="who recorded")
    parser.add_argument("--notes", default="", help="free text stored with the session")
    parser.add_argument("--condition", action="append", default=[], metavar="KEY=VALUE",
                        help="experimental condition to store (repeatable)")
    parser.add_argument("--compression", choices=COMPRESSIONS, default=None,
                        help="frame storage (default: [record] compression of the rig config)")
    parser.add_argument("--calib", metavar="CALIB.yaml", default=None,
                        help="calibration file to store with the session")
    add_config_option(parser)
    parser.set_defaults(func=run)


def _conditions(pairs: list[str]) -> dict[str, object]:
    out: dict[str, object] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise VbfeError(f"--condition {pair!r} is not KEY=VALUE")
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = value
    return out


def run(args: argparse.Namespace) -> int:
    """Record until the duration is reached, a device is gone or Ctrl-C."""
    calibration, calibration_size = None, None
    if args.calib:
        from vbfe.calib.calibration import Calibration  # checked before anything is recorded

        loaded = Calibration.load(args.calib)
        calibration, calibration_size = loaded.to_yaml_text(), loaded.image_size
    bar = progress(total=None, desc="recording", unit="frame")

    def show(stats: RecorderStats) -> None:
        bar.n = stats.frames
        bar.set_postfix_str(f"{stats.elapsed_s:.1f} s, {stats.samples} force samples, "
                            f"dropped {sum(stats.dropped.values())}, "
                            f"{stats.write_rate_mb_s:.0f} MB/s", refresh=True)

    try:
        stats = record_session(config_from(args), args.output, args.duration,
                               operator=args.operator, notes=args.notes,
                               conditions=_conditions(args.condition),
                               compression=args.compression, calibration_yaml=calibration,
                               calibration_size=calibration_size, calibration_name=args.calib,
                               on_progress=show)
        show(stats)
    finally:
        bar.close()
    print(f"{args.output}: {stats.frames} frames, {stats.samples} force samples, "
          f"{stats.elapsed_s:.2f} s, dropped {stats.dropped}; {stats.end_reason}")
    return 0
