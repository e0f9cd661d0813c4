"""`vbfe calibrate board|capture|stereo|projector|check`: stereo and projector calibration."""

from __future__ import annotations

import argparse

from vbfe.calib import commands
from vbfe.calib.capture import coverage_text
from vbfe.calib.report import summary_rows
from vbfe.cli.common import add_config_option, check_output_path, config_from, progress


def _board_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("board (defaults: the [calib] table of the rig config)")
    group.add_argument("--squares-x", type=int, dest="squares_x")
    group.add_argument("--squares-y", type=int, dest="squares_y")
    group.add_argument("--square-mm", type=float, dest="square_mm")
    group.add_argument("--marker-mm", type=float, dest="marker_mm")
    group.add_argument("--dictionary", help="ArUco dictionary, e.g. DICT_5X5_100")
    group.add_argument("--legacy", action="store_true", default=None,
                       help="board printed with OpenCV < 4.6 (legacy ChArUco pattern)")


def _board(args: argparse.Namespace) -> dict:
    return {k: getattr(args, k) for k in ("squares_x", "squares_y", "square_mm", "marker_mm",
                                          "dictionary", "legacy")}


def _print_rows(rows: list[tuple[str, str]]) -> None:
    width = max(len(label) for label, _ in rows)
    for label, value in rows:
        print(f"  {label:<{width}}  {value}")


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `calibrate` subcommand and its actions."""
    parser = sub.add_parser("calibrate", help="ChArUco stereo and projector calibration",
                            description="Print a board, capture views, calibrate the stereo "
                            "endoscope and the projector, check a calibration.")
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")

    p = actions.add_parser("board", help="write a printable ChArUco board (PNG + true-scale PDF)")
    p.add_argument("out", help="output path without extension, e.g. board_9x7")
    _board_options(p)
    add_config_option(p)
    p.set_defaults(func=run_board)

    p = actions.add_parser("capture", help="keep views of the board at new poses (PNG pairs)")
    p.add_argument("folder", help="folder for view_NNN_left.png / view_NNN_right.png")
    p.add_argument("--max-frames", type=int, default=200, help="stop after this many frames")
    p.add_argument("--headless", action="store_true",
                   help="no preview window (corners and coverage): print coverage bars as text")
    p.add_argument("--seed", type=int, default=None, help="simulated bench: pose seed")
    _board_options(p)
    add_config_option(p)
    p.set_defaults(func=run_capture)

    p = actions.add_parser("stereo", help="calibrate the stereo pair from views")
    p.add_argument("source", help="folder of view pairs or a session .h5")
    p.add_argument("-o", "--out", default="calibration.yaml", help="calibration YAML to write")
    p.add_argument("--no-report", action="store_true", help="skip the PNG/HTML report")
    p.add_argument("--store-in", metavar="SESSION.h5",
                   help="also store the calibration inside this session")
    _board_options(p)
    add_config_option(p)
    p.set_defaults(func=run_stereo)

    p = actions.add_parser("projector", help="calibrate the projector (Gray code on the board)")
    p.add_argument("captures", help="folder of pose_NNN/ Gray-code captures")
    p.add_argument("--calibration", required=True, help="stereo calibration YAML (or session)")
    p.add_argument("-o", "--out", help="YAML to write (default: update --calibration)")
    p.add_argument("--simulate", type=int, default=0, metavar="N",
                   help="first render N poses on the simulated bench into CAPTURES")
    p.add_argument("--seed", type=int, default=None)
    _board_options(p)
    add_config_option(p)
    p.set_defaults(func=run_projector)

    p = actions.add_parser("check", help="go/no-go of the stored calibration")
    p.add_argument("stored", help="stored calibration YAML (or session)")
    p.add_argument("--against", help="a new calibration YAML to compare with")
    p.add_argument("--views", help="folder of fresh view pairs (or a session)")
    p.add_argument("--max-depth-error-mm", type=float, default=None,
                   help="limit at the working distance (default: [calib] table)")
    _board_options(p)
    add_config_option(p)
    p.set_defaults(func=run_check)


def run_board(args: argparse.Namespace) -> int:
    """Write the board files."""
    png, pdf = commands.make_board(config_from(args), args.out, **_board(args))
    print(f"wrote {png} and {pdf} (print the PDF at 100% scale, no fitting)")
    return 0


def run_capture(args: argparse.Namespace) -> int:
    """Collect views, showing coverage."""
    preview = None
    if not args.headless:
        from vbfe.calib.preview import CapturePreview

        preview = CapturePreview()
    with progress(total=args.max_frames, desc="frames", unit="frame") as bar:
        def on_view(verdict, collector, left) -> None:
            bar.update(1)
            if preview is not None:
                preview.update_view(verdict, collector, left)
            else:
                bar.write(f"{verdict.reason[:60]:<60} | "
                          f"{coverage_text(collector.coverage(), len(collector.pairs))}")

        try:
            result = commands.capture(config_from(args), args.folder, args.max_frames,
                                      args.seed, on_view, **_board(args))
        finally:
            if preview is not None:
                preview.dispose()
    print(f"kept {len(result.names)} views of {result.frames_seen} frames in {result.folder}; "
          f"refused: {result.rejections or 'none'}")
    print("enough views for calibration" if result.enough else
          "not enough views yet: run capture again into the same folder with other poses")
    return 0


def run_stereo(args: argparse.Namespace) -> int:
    """Calibrate and print the summary."""
    check_output_path(args.out, "calibration file")
    with progress(desc="detecting corners", unit="view") as bar:
        outcome = commands.stereo(config_from(args), args.source, args.out,
                                  report=not args.no_report, store_in_session=args.store_in,
                                  step=lambda: bar.update(1), **_board(args))
    result = outcome.result
    print(f"wrote {outcome.yaml_path}" + (f", report {outcome.report_paths[1]}"
                                          if outcome.report_paths else ""))
    _print_rows(summary_rows(result.calibration))
    for name, why in result.dropped.items():
        print(f"  dropped {name}: {why}")
    rejected = result.calibration.info["rejected_corners"]
    if rejected:
        print(f"  rejected {len(rejected)} outlier corners (listed in the report)")
    return 0


def run_projector(args: argparse.Namespace) -> int:
    """Calibrate the projector and print its intrinsics."""
    with progress(total=1, desc="projector calibration") as bar:
        calibration = commands.projector(config_from(args), args.captures, args.calibration,
                                         args.out, args.simulate, args.seed, **_board(args))
        bar.update(1)
    K = calibration.K_proj
    print(f"projector fx={K[0, 0]:.2f} fy={K[1, 1]:.2f} cx={K[0, 2]:.2f} cy={K[1, 2]:.2f} px, "
          f"RMS {calibration.rms_projector_px:.3f} px; T (left->projector) = "
          f"{', '.join(f'{v * 1e3:.2f}' for v in calibration.T_proj)} mm; "
          f"wrote {args.out or args.calibration}")
    return 0


def run_check(args: argparse.Namespace) -> int:
    """Print the comparison; exit 1 on NO-GO."""
    with progress(total=1, desc="checking") as bar:
        result = commands.check(config_from(args), args.stored, args.against, args.views,
                                args.max_depth_error_mm, **_board(args))
        bar.update(1)
    _print_rows(result.rows())
    return 0 if result.passed else 1
