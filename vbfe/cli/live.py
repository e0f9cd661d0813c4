"""`vbfe live`: force estimated from the endoscope at frame rate, beside the trocar."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vbfe.cli.common import (
    add_config_option,
    add_settle_option,
    check_settle,
    positive,
    rig_from,
    settle_values,
)
from vbfe.cli.foxglove_options import add_foxglove_options, foxglove_server
from vbfe.cli.outputs import check_outputs

DEVICES = ("auto", "cpu", "cuda")


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `live` subcommand."""
    parser = sub.add_parser(
        "live",
        help="estimate force live from the endoscope with a trained model",
        description="Camera frames -> rectify -> SGBM + De Bruijn verification -> cloud -> "
        "model -> force, continuously, each stage on its own thread; the newest frame wins "
        "when a stage is slower than the camera (skipped frames are counted). Shows the "
        "estimate over the trocar's force, or prints a status line with --headless. Defaults "
        "come from the [live] table.",
    )
    parser.add_argument(
        "--model", metavar="MODEL.pt", help="from vbfe train (default: the rig's [live] model)"
    )
    parser.add_argument(
        "--calib",
        metavar="CALIB.yaml",
        help="calibration of this camera mode, or a session that stores one (default: the "
        "rig's [calib] calibration)",
    )
    add_settle_option(parser, "the model and calibration ([live] model, [calib] calibration)")
    parser.add_argument(
        "--record",
        metavar="SESSION.h5",
        default=None,
        help="also record the session, with the estimate stream",
    )
    parser.add_argument(
        "--duration",
        type=positive(float),
        default=None,
        metavar="SECONDS",
        help="stop after this long (default: until closed or Ctrl-C)",
    )
    parser.add_argument("--headless", action="store_true", help="status lines instead of a window")
    parser.add_argument(
        "--lsl",
        nargs="?",
        const="",
        default=None,
        metavar="SOURCE_ID",
        help="publish the estimates (LSL stream vbfe-estimate) and the trocar "
        "(vbfe-trocar) for other programs; SOURCE_ID tells two vbfe apart "
        "(default vbfe@HOST; docs/how-to/publish-streams.md)",
    )
    parser.add_argument(
        "--udp",
        metavar="HOST:PORT",
        default=None,
        help="also send one JSON datagram per estimate to HOST:PORT",
    )
    parser.add_argument(
        "--scale",
        type=positive(float),
        default=None,
        help="reconstruct at this fraction of the camera resolution (e.g. 0.5)",
    )
    parser.add_argument(
        "--row-scale",
        type=positive(float),
        default=None,
        help="match this fraction of the (scaled) rows, at full width ([live] "
        "default 0.5: rows averaged in pairs, half the matching cost, the same "
        "depth resolution; 1: every row)",
    )
    parser.add_argument(
        "--no-verify",
        action="store_true",
        help="skip the De Bruijn verification (faster, bare SGBM)",
    )
    parser.add_argument(
        "--device",
        choices=DEVICES,
        default=None,
        help="where the model runs (auto: CUDA when torch sees it)",
    )
    add_foxglove_options(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run live estimation and print the summary."""
    from vbfe.calib import load_calibration
    from vbfe.common.errors import LiveError
    from vbfe.estimate import load_model
    from vbfe.live.outputs import EstimateOutput, LslOutput, UdpOutput, udp_address
    from vbfe.live.run import live_estimator, live_run, run_headless

    rig = rig_from(args)
    settings = rig.live
    args.model = args.model or settings.model or None
    args.calib = args.calib or rig.calib.calibration or None
    for option, value, key in (
        ("--model", args.model, "[live] model"),
        ("--calib", args.calib, "[calib] calibration"),
    ):
        if value is None:
            raise LiveError(f"give {option}: the rig file sets no {key} ({rig.banner()})")
    check_outputs([args.record], [args.model, args.calib], writes="session")  # a new file
    check_settle(args)
    udp = udp_address(args.udp) if args.udp is not None else None
    for option, value in (("--scale", args.scale), ("--row-scale", args.row_scale)):
        if value is not None and value > 1:
            raise LiveError(
                f"{option} {value}: give a fraction of the camera resolution in (0, 1], e.g. 0.5"
            )
    calibration = load_calibration(args.calib)
    model = load_model(args.model)
    settle_values(
        args,
        {
            "live": {"model": str(Path(args.model).resolve())},
            "calib": {"calibration": str(Path(args.calib).resolve())},
        },
    )
    server = foxglove_server(args, model.config.target)
    estimator = live_estimator(
        rig,
        model,
        calibration,
        args.scale,
        not args.no_verify,
        args.device,
        args.row_scale,
    )
    per_protocol = ", ".join(f"{p} {m}" for p, (m, _) in model.by_protocol.items())
    print(
        f"model {args.model}: {estimator.model.selected} (selected by its training run"
        + (
            f"; per protocol {per_protocol}: [live] protocol names the one run"
            if per_protocol
            else ""
        )
        + ")"
    )
    print(estimator.describe())
    outputs: list[EstimateOutput] = []
    if args.lsl is not None:
        outputs.append(LslOutput(model.config.target, *([args.lsl] if args.lsl else [])))
    if udp is not None:
        outputs.append(UdpOutput(udp, model.config.target))
    if server is not None:
        outputs.append(server)
    live = live_run(rig, estimator, calibration, args.calib, args.record, str(args.model), outputs)
    live.start(args.duration if args.record else None)
    if args.headless:
        status = run_headless(
            live, args.duration, lambda s: print(s.line(), flush=True), settings.status_interval_s
        )
    else:
        from vbfe.live.viewer import show_live

        status = show_live(live, args.duration)
    if live.error:
        raise LiveError(f"live estimation stopped: {live.error}")
    print(
        f"{status.estimates} estimates from {status.frames} frames ({status.skipped} skipped) "
        f"in {status.wall_s:.1f} s; latency p50 {status.latency_p50_ms:.1f} ms, p95 "
        f"{status.latency_p95_ms:.1f} ms; MAE vs trocar {status.mae_n:.3f} N "
        f"(raw host times, {status.mae_count} estimates)"
    )
    if server is not None:
        print(server.summary())
        if server.error:
            print(f"Foxglove: the viewer stopped early ({server.error}); the run went on")
    if args.record:
        recorded = live.acquisition.stats
        print(
            f"session with estimate stream: {args.record}: {recorded.frames} frames, "
            f"{recorded.queue_dropped.get('camera', 0)} lost by its writer (the estimate "
            f"skips frames first; score it: vbfe evaluate --live {args.record})",
            file=sys.stdout,
        )
    return 0
