"""`vbfe record`: record stereo video, trocar force and projector events into a session file."""

from __future__ import annotations

import argparse
import sys
from functools import partial

from vbfe.acquire import AcquisitionStats, record_session
from vbfe.acquire.recording.remote import (
    DEFAULT_PORT,
    RemoteControl,
    RemoteRecording,
    RemoteSessions,
    serve,
)
from vbfe.acquire.recording.sync_session import SyncProtocol
from vbfe.acquire.session.layout import COMPRESSIONS
from vbfe.cli.common import add_config_option, progress, rig_from
from vbfe.cli.foxglove_options import add_foxglove_options, foxglove_server
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.common.errors import VbfeError
from vbfe.common.settings import parse_conditions


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `record` subcommand."""
    parser = sub.add_parser(
        "record",
        help="record a session (stereo video + force + projector) until Ctrl-C or --duration",
    )
    parser.add_argument(
        "output",
        metavar="SESSION.h5",
        nargs="?",
        default=None,
        help="new session file (not with --remote)",
    )
    parser.add_argument(
        "--duration",
        type=_positive_seconds,
        default=None,
        metavar="S",
        help="stop after this many seconds of video (default: Ctrl-C)",
    )
    parser.add_argument("--operator", default="", help="who recorded")
    parser.add_argument("--notes", default="", help="free text stored with the session")
    parser.add_argument(
        "--condition",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="experimental condition to store (repeatable)",
    )
    parser.add_argument(
        "--compression",
        choices=COMPRESSIONS,
        default=None,
        help="frame storage (default: [record] compression of the rig config)",
    )
    parser.add_argument(
        "--calib",
        metavar="CALIB.yaml",
        default=None,
        help="calibration file to store with the session (default: the rig's [calib] "
        "calibration, when it settles one)",
    )
    parser.add_argument(
        "--tare",
        action="store_true",
        help="zero the unloaded trocar from its first [record] tare_samples "
        "samples before recording (the offset is stored with the session)",
    )
    add_overwrite_option(parser)
    parser.add_argument(
        "--protocol",
        choices=("traction", "sync"),
        default="traction",
        help="sync: a short sync check session (projector flashes, operator "
        "taps; --duration defaults to 20 s), then run verify-sync on it",
    )
    parser.add_argument(
        "--taps",
        type=int,
        default=20,
        metavar="N",
        help="taps the operator is asked for (sync protocol)",
    )
    parser.add_argument(
        "--flashes", type=int, default=20, metavar="N", help="projector flashes (sync protocol)"
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=None,
        help="seed of the random flash times (sync protocol; default: fresh)",
    )
    parser.add_argument(
        "--remote",
        type=int,
        default=None,
        metavar="PORT",
        help=f"wait for LabRecorder's remote-control commands on this TCP port "
        f"(its default: {DEFAULT_PORT}; 0: any free port) and record whenever "
        "told to (docs/how-to/publish-streams.md); Ctrl-C to quit",
    )
    parser.add_argument(
        "--remote-bind",
        default="127.0.0.1",
        metavar="ADDRESS",
        help="address the remote-control port listens on (default: localhost "
        "only; 0.0.0.0 for every interface)",
    )
    add_foxglove_options(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def _positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def run(args: argparse.Namespace) -> int:
    """Record until the duration is reached, a device is gone or Ctrl-C."""
    if args.remote is not None:
        if args.output or args.duration or args.protocol != "traction" or args.tare:
            raise VbfeError(
                "--remote records into the files the `filename` command names, "
                "until `stop`: drop SESSION.h5, --duration, --protocol and --tare"
            )
    elif args.output is None:
        raise VbfeError(
            "name the new session file (SESSION.h5), or wait for remote-control "
            "commands with --remote PORT"
        )
    args.calib = args.calib or rig_from(args).calib.calibration or None  # the rig's settled one
    check_outputs(
        [args.output] if args.output else [], [args.calib], args.overwrite, writes="session"
    )
    calibration, calibration_size = None, None
    if args.calib:
        from vbfe.calib import Calibration  # checked before anything is recorded

        loaded = Calibration.load(args.calib)
        calibration, calibration_size = loaded.to_yaml_text(), loaded.image_size
    if args.remote is not None:
        if args.foxglove is not None:
            raise VbfeError("--foxglove serves one recording: drop it with --remote")
        return _run_remote(args, calibration, calibration_size)
    server = foxglove_server(args)
    protocol = None
    if args.protocol == "sync":
        protocol = SyncProtocol(
            taps=args.taps, flashes=args.flashes, duration_s=args.duration or 20.0, seed=args.seed
        )
        print(protocol.instructions(), file=sys.stderr)
    bar = progress(total=None, desc="recording", unit="frame")

    def show(stats: AcquisitionStats) -> None:
        bar.n = stats.frames
        events = f"{protocol.progress()}, " if protocol else ""
        bar.set_postfix_str(
            f"{events}{stats.elapsed_s:.1f} s, {stats.samples} force samples, "
            f"dropped {sum(stats.dropped.values())}, "
            f"{stats.write_rate_mb_s:.0f} MB/s",
            refresh=True,
        )

    try:
        stats = record_session(
            rig_from(args),
            args.output,
            args.duration,
            operator=args.operator,
            notes=args.notes,
            conditions=parse_conditions(args.condition),
            compression=args.compression,
            calibration_yaml=calibration,
            on_progress=show,
            tare=args.tare,
            overwrite=args.overwrite,
            protocol=protocol,
            calibration_size=calibration_size,
            calibration_name=args.calib,
            on_warning=lambda w: bar.write(f"vbfe record: warning: {w}", file=sys.stderr),
            listeners=(server,) if server is not None else (),
        )
        show(stats)
    finally:
        bar.close()
    extra = "".join(
        f", {stream} {n} samples"
        for stream, n in stats.counts.items()
        if stream not in ("camera", "force", "projector")
    )
    print(
        f"{args.output}: {stats.frames} frames, {stats.samples} force samples{extra}, "
        f"{stats.elapsed_s:.2f} s, dropped {stats.dropped}; {stats.end_reason}"
    )
    _print_stream_accounting(args.output, stats)
    if server is not None:
        print(server.summary(recording=True))
        if server.error:
            print(f"Foxglove: the viewer stopped early ({server.error}); the run went on")
    if protocol is not None:
        print(
            f"sync protocol: collected {protocol.progress()}; check it with "
            f"`vbfe verify-sync {args.output}`"
        )
    return 0


def _print_stream_accounting(path: str, stats: AcquisitionStats) -> None:
    """One line per extra stream: samples lost by the recorder vs the publisher's timing."""
    from vbfe.acquire import SessionReader
    from vbfe.acquire.session.extra_streams import stream_accounting

    extra = [s for s in stats.counts if s not in ("camera", "force", "projector")]
    if not extra:
        return
    with SessionReader(path) as reader:
        attrs = reader.attrs
    for stream in extra:
        print(f"stream {stream}: " + stream_accounting(attrs, stream).text(stats.counts[stream]))


def _run_remote(
    args: argparse.Namespace, calibration: str | None, calibration_size: tuple[int, int] | None
) -> int:
    """Serve LabRecorder's commands: each start..stop records one session."""
    begin = partial(
        RemoteRecording,
        rig_from(args),
        operator=args.operator,
        notes=args.notes,
        conditions=parse_conditions(args.condition),
        compression=args.compression,
        calibration_yaml=calibration,
        calibration_size=calibration_size,
        calibration_name=args.calib,
        overwrite=args.overwrite,
    )
    sessions = RemoteSessions(begin, args.overwrite, on_message=lambda m: print(m, flush=True))
    server = RemoteControl(sessions, args.remote, args.remote_bind)
    serve(
        server,
        lambda port: print(
            f"remote control: listening on {args.remote_bind}:{port} "
            "(filename, start, stop, update, select all, mark; Ctrl-C "
            "quits)",
            flush=True,
        ),
    )
    print(
        f"remote control: {len(sessions.finished)} session(s) recorded"
        + "".join(f"\n  {path}" for path in sessions.finished)
    )
    return 0
