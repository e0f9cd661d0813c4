"""`vbfe calibrate board|capture|camera|stereo|projector-capture|projector|check|export|color`:
single-camera, stereo, projector and colour calibration, checks and export to ROS / Kalibr /
OpenCV files."""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any

from vbfe.calib import commands
from vbfe.calib.board import TARGETS
from vbfe.calib.camera import uncertainty_text
from vbfe.calib.capture import coverage_text
from vbfe.calib.errors import CalibrationError
from vbfe.calib.export import FORMATS
from vbfe.calib.report import summary_rows
from vbfe.calib.views import NAMING_RULES
from vbfe.cli.common import add_config_option, config_from, progress
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.config import section

_BOARD_KEYS = ("target", "squares_x", "squares_y", "inner_corners", "square_mm", "marker_mm",
               "dictionary", "legacy")


def _board_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("board (defaults: the [calib] table of the rig config)")
    group.add_argument("--target", choices=TARGETS,
                       help="ChArUco board or plain chessboard (default: [calib] target)")
    group.add_argument("--squares-x", type=int, dest="squares_x", help="ChArUco squares along x")
    group.add_argument("--squares-y", type=int, dest="squares_y", help="ChArUco squares along y")
    group.add_argument("--inner-corners", metavar="NXxNY", dest="inner_corners",
                       help="chessboard inner corners, e.g. 9x6 (OpenCV's left01.jpg set)")
    group.add_argument("--square-mm", type=float, dest="square_mm", help="square side (mm)")
    group.add_argument("--marker-mm", type=float, dest="marker_mm",
                       help="ChArUco marker side (mm)")
    group.add_argument("--dictionary", help="ArUco dictionary, e.g. DICT_5X5_100")
    group.add_argument("--legacy", action="store_true", default=None,
                       help="board printed with OpenCV < 4.6 (legacy ChArUco pattern)")


def _board(args: argparse.Namespace) -> dict[str, Any]:
    board = {k: getattr(args, k, None) for k in _BOARD_KEYS}
    if board["inner_corners"] is not None:
        m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", board["inner_corners"])
        if not m:
            raise CalibrationError(f"--inner-corners {board['inner_corners']!r}: give the inner "
                                   "corners as NXxNY, e.g. 9x6")
        board["inner_corners"] = (int(m[1]), int(m[2]))
    return board


def _solve_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--fix-k3", action="store_true", default=None,
                        help="solve k1, k2, p1, p2 only (k3 = 0, as Kalibr's radtan model)")


def _config_and_board(args: argparse.Namespace) -> tuple[dict, dict[str, Any]]:
    """The rig config and board overrides, the board checked before any work starts."""
    config, board = config_from(args), _board(args)
    commands.board_spec(config, **board)
    return config, board


def _print_rows(rows: list[tuple[str, str]]) -> None:
    width = max(len(label) for label, _ in rows)
    for label, value in rows:
        print(f"  {label:<{width}}  {value}")


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `calibrate` subcommand and its actions."""
    parser = sub.add_parser("calibrate", help="camera, stereo and projector calibration",
                            description="Print a board, capture views, calibrate one camera, the "
                            "stereo endoscope and the projector (ChArUco or chessboard), check "
                            "a calibration, export it to ROS / Kalibr / OpenCV files.")
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")

    p = actions.add_parser("board", help="write a printable ChArUco board (PNG + true-scale PDF)")
    p.add_argument("out", help="output path without extension, e.g. board_9x7")
    _board_options(p)
    add_overwrite_option(p)
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

    p = actions.add_parser("projector-capture",
                           help="show the Gray-code sequence at board poses, keep the camera's "
                           "images (pose_NNN/ folders for 'projector')")
    p.add_argument("out", help="folder for pose_NNN/ (new poses go after those already there)")
    p.add_argument("--poses", type=int, default=8, help="board poses to capture (default 8)")
    p.add_argument("--seed", type=int, default=None, help="simulated bench: pose seed")
    add_config_option(p)
    p.set_defaults(func=run_projector_capture)

    p = actions.add_parser("camera", help="calibrate one camera from views of the board",
                           description="Calibrate one camera: intrinsics, distortion, per-view "
                           "RMS and standard deviations, written as a camera YAML that "
                           "'calibrate stereo --intrinsics' can use as fixed intrinsics.")
    p.add_argument("source", help="folder of images, a quoted glob ('views/*.jpg'), or with "
                   "--eye any stereo view source (folder of pairs, session)")
    p.add_argument("-o", "--out", default="camera.yaml", help="camera YAML to write")
    p.add_argument("--eye", choices=("left", "right"),
                   help="take this eye of stereo views (" + NAMING_RULES + ")")
    _solve_options(p)
    _board_options(p)
    add_config_option(p)
    p.set_defaults(func=run_camera)

    p = actions.add_parser("stereo", help="calibrate the stereo pair from views",
                           description="Calibrate the stereo pair; " + NAMING_RULES + ". "
                           "A result with an impossible baseline, a rectified principal point "
                           "outside the image, a rectification keeping less than half the image "
                           "or a high RMS is refused and nothing is written.")
    p.add_argument("source", nargs="?", help="folder of view pairs or a session .h5")
    p.add_argument("--left", metavar="GLOB", dest="left_glob",
                   help="left images (quoted glob), paired in sorted order with --right")
    p.add_argument("--right", metavar="GLOB", dest="right_glob", help="right images (glob)")
    p.add_argument("--intrinsics", nargs=2, metavar=("LEFT.yaml", "RIGHT.yaml"),
                   help="fix the intrinsics to these 'calibrate camera' files")
    p.add_argument("--nominal-baseline-mm", type=float, default=None, metavar="MM",
                   help="refuse a baseline far from this (default: [calib] nominal_baseline_mm; "
                   "0 = not checked)")
    p.add_argument("-o", "--out", default="calibration.yaml", help="calibration YAML to write")
    p.add_argument("--no-report", action="store_true", help="skip the PNG/HTML report")
    p.add_argument("--store-in", metavar="SESSION.h5",
                   help="also store the calibration inside this session")
    _solve_options(p)
    _board_options(p)
    add_overwrite_option(p)
    add_config_option(p)
    p.set_defaults(func=run_stereo)

    p = actions.add_parser("export", help="write a calibration as ROS, Kalibr or OpenCV files")
    p.add_argument("calibration", help="calibration YAML (or session)")
    p.add_argument("--format", required=True, choices=FORMATS, dest="fmt",
                   help="ros: <stem>_left.yaml + <stem>_right.yaml camera_info; kalibr: "
                   "<stem>-camchain.yaml; opencv: intrinsics.yml + extrinsics.yml")
    p.add_argument("--out-dir", help="folder to write into (default: next to the calibration)")
    p.set_defaults(func=run_export)

    p = actions.add_parser("projector", help="calibrate the projector (Gray code on the board)")
    p.add_argument("captures", help="folder of pose_NNN/ Gray-code captures")
    p.add_argument("--calibration", required=True, help="stereo calibration YAML (or session)")
    p.add_argument("-o", "--out", help="YAML to write (default: update --calibration)")
    p.add_argument("--simulate", type=int, default=0, metavar="N",
                   help="first capture N poses into CAPTURES with the rig's camera and projector "
                   "(as projector-capture; rendered on the simulated bench)")
    p.add_argument("--seed", type=int, default=None)
    _board_options(p)
    add_overwrite_option(p)
    add_config_option(p)
    p.set_defaults(func=run_projector)

    p = actions.add_parser("check", help="go/no-go of the stored calibration")
    p.add_argument("stored", help="stored calibration YAML (or session)")
    p.add_argument("--against", help="a new calibration YAML to compare with")
    p.add_argument("--views", help="folder of fresh view pairs (or a session)")
    p.add_argument("--max-depth-error-mm", type=float, default=None,
                   help="limit at the working distance (default: [calib] table)")
    p.add_argument("--nominal-baseline-mm", type=float, default=None, metavar="MM",
                   help="NO-GO for a baseline far from this (default: [calib] table)")
    _board_options(p)
    add_config_option(p)
    p.set_defaults(func=run_check)

    p = actions.add_parser("color", help="fit the colour crosstalk model (flat projections)")
    p.add_argument("calibration", help="calibration YAML to add color_mixing/color_offset to")
    p.add_argument("-o", "--out", default=None, help="write here instead of in place")
    p.add_argument("--frames", type=int, default=3, help="frames averaged per projection")
    add_config_option(p)
    p.set_defaults(func=run_color)


def run_board(args: argparse.Namespace) -> int:
    """Write the board files."""
    config, board = _config_and_board(args)
    check_outputs([Path(args.out).with_suffix(".png"), Path(args.out).with_suffix(".pdf")],
                  overwrite=args.overwrite)
    png, pdf = commands.make_board(config, args.out, **board)
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
            config, board = _config_and_board(args)
            result = commands.capture(config, args.folder, args.max_frames, args.seed, on_view,
                                      **board)
        finally:
            if preview is not None:
                preview.dispose()
    print(f"kept {len(result.names)} views of {result.frames_seen} frames in {result.folder}; "
          f"refused: {result.rejections or 'none'}")
    print("enough views for calibration" if result.enough else
          "not enough views yet: run capture again into the same folder with other poses")
    return 0


def _print_solve_notes(dropped: dict[str, str], n_rejected: int, weak: str | None) -> None:
    for name, why in dropped.items():
        print(f"  dropped {name}: {why}")
    if n_rejected:
        print(f"  rejected {n_rejected} outlier corners (residual above the limit)")
    if weak:
        print(f"  {weak}")


def run_camera(args: argparse.Namespace) -> int:
    """Calibrate one camera and print intrinsics, σ and what was left out."""
    config, board = _config_and_board(args)
    with progress(desc="detecting corners", unit="image") as bar:
        result = commands.camera(config, args.source, args.out, args.eye,
                                 step=lambda: bar.update(1), fix_k3=args.fix_k3, **board)
    model = result.model
    K = model.K
    print(f"wrote {args.out}")
    _print_rows([("image size", f"{model.image_size[0]} x {model.image_size[1]} px"),
                 ("fx, fy", f"{K[0, 0]:.2f}, {K[1, 1]:.2f} px"),
                 ("cx, cy", f"{K[0, 2]:.2f}, {K[1, 2]:.2f} px"),
                 ("distortion", ", ".join(f"{d:.5f}" for d in model.D)),
                 ("RMS", f"{model.rms_px:.3f} px over {len(result.names)} views (per view "
                  f"{model.per_view_rms_px.min():.3f} to {model.per_view_rms_px.max():.3f})"),
                 ("uncertainty", uncertainty_text(K, model.std_intrinsics))])
    _print_solve_notes(result.dropped, len(result.fit.rejected), result.weak)
    return 0


def run_stereo(args: argparse.Namespace) -> int:
    """Calibrate and print the summary."""
    check_outputs([args.out], [args.source, args.store_in], args.overwrite)
    config, board = _config_and_board(args)
    intrinsics = tuple(args.intrinsics) if args.intrinsics else None
    with progress(desc="detecting corners", unit="view") as bar:
        outcome = commands.stereo(config, args.source, args.out, report=not args.no_report,
                                  store_in_session=args.store_in, step=lambda: bar.update(1),
                                  left_glob=args.left_glob, right_glob=args.right_glob,
                                  intrinsics=intrinsics,
                                  nominal_baseline_mm=args.nominal_baseline_mm,
                                  fix_k3=args.fix_k3, **board)
    result = outcome.result
    print(f"wrote {outcome.yaml_path}" + (f", report {outcome.report_paths[1]}"
                                          if outcome.report_paths else ""))
    _print_rows(summary_rows(result.calibration))
    for eye, fit in (("left", result.left), ("right", result.right)):
        print(f"  {eye} " + uncertainty_text(fit.K, fit.std_intrinsics)
              + (" (fixed from --intrinsics)" if intrinsics else ""))
    _print_solve_notes(result.dropped, len(result.calibration.info["rejected_corners"]),
                       None)  # a weak result is noted in the summary rows
    return 0


def run_export(args: argparse.Namespace) -> int:
    """Write the calibration in another tool's format."""
    for path in commands.export(args.calibration, args.fmt, args.out_dir):
        print(f"wrote {path}")
    return 0


def run_projector_capture(args: argparse.Namespace) -> int:
    """Capture Gray-code poses, saying what the capture waits for."""
    with progress(total=args.poses, desc="poses", unit="pose") as bar:
        def on_event(message: str) -> None:
            bar.write(message)
            if message.startswith("kept"):
                bar.update(1)

        written = commands.projector_capture(config_from(args), args.out, args.poses, args.seed,
                                             on_event)
    print(f"wrote {len(written)} poses into {args.out}; calibrate with "
          f"'vbfe calibrate projector {args.out} --calibration CALIBRATION.yaml'")
    return 0


def run_projector(args: argparse.Namespace) -> int:
    """Calibrate the projector and print its intrinsics (without -o: update --calibration)."""
    check_outputs([args.out], [args.captures, args.calibration], args.overwrite)
    with progress(total=1, desc="projector calibration") as bar:
        config, board = _config_and_board(args)
        calibration = commands.projector(config, args.captures, args.calibration,
                                         args.out, args.simulate, args.seed, **board)
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
        config, board = _config_and_board(args)
        result = commands.check(config, args.stored, args.against, args.views,
                                args.max_depth_error_mm, args.nominal_baseline_mm, **board)
        bar.update(1)
    _print_rows(result.rows())
    return 0 if result.passed else 1


def run_color(args: argparse.Namespace) -> int:
    """Project flat colours, fit the crosstalk model and store it in the calibration."""
    from vbfe.calib.calibration import load_calibration
    from vbfe.acquire import frame_feed
    from vbfe.drivers.registry import open_rig
    from vbfe.recon.color import capture_color_model

    from vbfe.calib.options import calib_settings

    calibration = load_calibration(args.calibration)
    config = config_from(args)
    settle_s = calib_settings(section(config, "calib")).projector_settle_s
    rig = open_rig(config, families=("camera", "projector"))
    with frame_feed(rig) as frames:
        model = capture_color_model(frames, rig.projector, frames=args.frames,
                                    settle_s=settle_s)
    out = model.apply_to(calibration).save(args.out or args.calibration)
    rows = "; ".join(" ".join(f"{v:.3f}" for v in row) for row in model.mixing)
    print(f"colour mixing (camera BGR <- projector BGR) [{rows}], offset "
          f"{' '.join(f'{v:.1f}' for v in model.offset)}; wrote {out}")
    return 0
