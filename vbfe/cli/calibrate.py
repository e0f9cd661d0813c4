"""`vbfe calibrate board|capture|camera|stereo|projector-capture|projector|check|import|export|
color`: single-camera, stereo, projector and colour calibration, checks, and import from / export
to OpenCV, Kalibr, ROS and Middlebury files."""

from __future__ import annotations

import argparse
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vbfe.calib import commands
from vbfe.calib.board import TARGETS
from vbfe.calib.camera import uncertainty_text
from vbfe.calib.capture import coverage_text
from vbfe.calib.corner_choice import summary_rows as corner_rows
from vbfe.calib.export import FORMATS
from vbfe.calib.rectify import ZERO_DISPARITY
from vbfe.calib.report import gate_lines, summary_rows
from vbfe.calib.views import NAMING_RULES
from vbfe.cli.common import (
    add_config_option,
    add_settle_option,
    check_settle,
    positive,
    progress,
    rig_from,
    settle_values,
)
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.common.errors import CalibrationError
from vbfe.rig_config import RigConfig

_BOARD_KEYS = (
    "target",
    "squares_x",
    "squares_y",
    "inner_corners",
    "square_mm",
    "marker_mm",
    "dictionary",
    "legacy",
)


def _board_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("board (defaults: the [calib] table of the rig config)")
    group.add_argument(
        "--target",
        choices=TARGETS,
        help="ChArUco board or plain chessboard (default: [calib] target)",
    )
    group.add_argument("--squares-x", type=int, dest="squares_x", help="ChArUco squares along x")
    group.add_argument("--squares-y", type=int, dest="squares_y", help="ChArUco squares along y")
    group.add_argument(
        "--inner-corners",
        metavar="NXxNY",
        dest="inner_corners",
        help="chessboard inner corners, e.g. 9x6 (OpenCV's left01.jpg set)",
    )
    group.add_argument("--square-mm", type=float, dest="square_mm", help="square side (mm)")
    group.add_argument("--marker-mm", type=float, dest="marker_mm", help="ChArUco marker side (mm)")
    group.add_argument("--dictionary", help="ArUco dictionary, e.g. DICT_5X5_100")
    group.add_argument(
        "--legacy",
        action="store_true",
        default=None,
        help="board printed with OpenCV < 4.6 (legacy ChArUco pattern)",
    )


def _board(args: argparse.Namespace) -> dict[str, Any]:
    board = {k: getattr(args, k, None) for k in _BOARD_KEYS}
    if board["inner_corners"] is not None:
        m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", board["inner_corners"])
        if not m:
            raise CalibrationError(
                f"--inner-corners {board['inner_corners']!r}: give the inner "
                "corners as NXxNY, e.g. 9x6"
            )
        board["inner_corners"] = (int(m[1]), int(m[2]))
    return board


def _solve_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--fix-k3",
        action="store_true",
        default=None,
        help="solve k1, k2, p1, p2 only (k3 = 0, as Kalibr's radtan model)",
    )


# the [calib] keys that gate flags set: flag, type, metavar, help
GateFlag = tuple[str, Callable[[str], Any], str, str]
_GATE_FLAGS: dict[str, GateFlag] = {
    "min_views": (
        "--min-views",
        positive(int),
        "N",
        "fewest usable views accepted (default: [calib] min_views)",
    ),
    "max_rms_px": (
        "--max-rms-px",
        positive(float),
        "PX",
        "refuse an RMS reprojection error above this (default: [calib] max_rms_px)",
    ),
    "nominal_baseline_mm": (
        "--nominal-baseline-mm",
        positive(float, zero=True),
        "MM",
        "refuse a baseline more than [calib] baseline_tolerance from this "
        "(0 = not checked; default: [calib] nominal_baseline_mm)",
    ),
    "working_distance_mm": (
        "--working-distance-mm",
        positive(float),
        "MM",
        "distance at which depth uncertainty is stated and checked "
        "(default: [calib] working_distance_mm; check: the stored one)",
    ),
    "check_max_depth_error_mm": (
        "--max-depth-error-mm",
        positive(float),
        "MM",
        "NO-GO above this depth error at the working distance "
        "(default: [calib] check_max_depth_error_mm)",
    ),
    "check_max_epipolar_px": (
        "--max-epipolar-px",
        positive(float),
        "PX",
        "NO-GO above this epipolar RMS of fresh views (default: [calib] check_max_epipolar_px)",
    ),
}


def _fraction(text: str) -> float:
    value = positive(float, zero=True)(text)
    if value > 1:
        raise argparse.ArgumentTypeError(f"must be within [0, 1], got {text}")
    return value


def _alpha(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if value != -1 and not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be -1 or within [0, 1], got {text}")
    return value


_STEREO_FLAGS: dict[str, GateFlag] = {
    "min_baseline_mm": (
        "--min-baseline-mm",
        positive(float, zero=True),
        "MM",
        "refuse a baseline below this (default: [calib] min_baseline_mm)",
    ),
    "baseline_tolerance": (
        "--baseline-tolerance",
        positive(float),
        "FRACTION",
        "refuse a baseline further than this fraction from the nominal one "
        "(default: [calib] baseline_tolerance)",
    ),
    "min_rectified_fraction": (
        "--min-rectified-fraction",
        _fraction,
        "FRACTION",
        "refuse a rectification keeping less than this fraction of an eye's image "
        "(default: [calib] min_rectified_fraction)",
    ),
    "rectify_alpha": (
        "--rectify-alpha",
        _alpha,
        "ALPHA",
        "-1: no free scaling (the rectified focal length is the eyes' fy, each eye's principal "
        "point stays put); 0-1: stereoRectify's free scaling, 0 = only valid pixels, 1 = the "
        "whole camera image "
        "(default: [calib] rectify_alpha)",
    ),
    "zero_disparity": (
        "--zero-disparity",
        str,
        "auto|on|off",
        "on: one principal point for both rectified eyes (OpenCV's CALIB_ZERO_DISPARITY); "
        "off: each eye keeps its own, their offset stored as doffs; auto: on unless that "
        "keeps less than --min-rectified-fraction (default: [calib] zero_disparity)",
    ),
}
_GATE_FLAGS.update(_STEREO_FLAGS)
# the gates a finished stereo calibration passes (import and check test only these)
_RIG_GATES = (
    "max_rms_px",
    "min_baseline_mm",
    "nominal_baseline_mm",
    "baseline_tolerance",
    "min_rectified_fraction",
)
_STEREO_GATES = (
    "min_views",
    *_RIG_GATES,
    "rectify_alpha",
    "zero_disparity",
    "working_distance_mm",
)


def _gate_options(parser: argparse.ArgumentParser, *keys: str) -> None:
    group = parser.add_argument_group(
        "limits and rectification (defaults: the [calib] table of the rig config)"
    )
    for key in keys:
        flag, kind, metavar, text = _GATE_FLAGS[key]
        choices = ZERO_DISPARITY if key == "zero_disparity" else None
        group.add_argument(
            flag, type=kind, dest=key, metavar=metavar, default=None, help=text, choices=choices
        )


def _settings(args: argparse.Namespace) -> dict[str, Any]:
    """The ``[calib]`` values the user states: the command-line flags (gates, --fix-k3) and,
    for the nominal baseline, the user's own rig file (--config)."""
    given = {key: getattr(args, key, None) for key in _GATE_FLAGS}
    if getattr(args, "fix_k3", None):
        given["fix_k3"] = True
    rig = rig_from(args)
    if given.get("nominal_baseline_mm") is None and rig.set_by_file("calib", "nominal_baseline_mm"):
        given["nominal_baseline_mm"] = rig.calib.nominal_baseline_mm
    return {key: value for key, value in given.items() if value is not None}


def _layout_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--ext",
        metavar="EXT",
        help="only images ending in this (e.g. png) where a folder holds one view twice "
        "(left01.jpg and left01.png)",
    )


def _config_and_board(args: argparse.Namespace) -> tuple[RigConfig, dict[str, Any]]:
    """The rig config and board overrides, the board checked before any work starts."""
    config, board = rig_from(args), _board(args)
    commands.board_spec(config, **board)
    return config, board


def _print_rows(rows: list[tuple[str, str]]) -> None:
    width = max(len(label) for label, _ in rows)
    for label, value in rows:
        print(f"  {label:<{width}}  {value}")


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `calibrate` subcommand and its actions."""
    parser = sub.add_parser(
        "calibrate",
        help="camera, stereo and projector calibration",
        description="Print a board, capture views, calibrate one camera, the "
        "stereo endoscope and the projector (ChArUco or chessboard), check "
        "a calibration, export it to ROS / Kalibr / OpenCV files.",
    )
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")

    p = actions.add_parser("board", help="write a printable ChArUco board (PNG + true-scale PDF)")
    p.add_argument("out", help="output path without extension, e.g. board_9x7")
    _board_options(p)
    add_overwrite_option(p)
    add_config_option(p)
    p.set_defaults(func=run_board)

    p = actions.add_parser("capture", help="keep views of the board at new poses (PNG pairs)")
    p.add_argument("folder", help="folder for view_NNN_left.png / view_NNN_right.png")
    p.add_argument(
        "--max-frames", type=positive(int), default=200, help="stop after this many frames"
    )
    p.add_argument(
        "--headless",
        action="store_true",
        help="no preview window (corners and coverage): print coverage bars as text",
    )
    p.add_argument("--seed", type=int, default=None, help="simulated bench: pose seed")
    _board_options(p)
    add_config_option(p)
    p.set_defaults(func=run_capture)

    p = actions.add_parser(
        "projector-capture",
        help="show the Gray-code sequence at board poses, keep the camera's "
        "images (pose_NNN/ folders for 'projector')",
    )
    p.add_argument("out", help="folder for pose_NNN/ (new poses go after those already there)")
    p.add_argument(
        "--poses", type=positive(int), default=8, help="board poses to capture (default 8)"
    )
    p.add_argument("--seed", type=int, default=None, help="simulated bench: pose seed")
    add_config_option(p)
    p.set_defaults(func=run_projector_capture)

    p = actions.add_parser(
        "camera",
        help="calibrate one camera from views of the board",
        description="Calibrate one camera: intrinsics, distortion, per-view "
        "RMS and standard deviations, written as a camera YAML that "
        "'calibrate stereo --intrinsics' can use as fixed intrinsics.",
    )
    p.add_argument(
        "source",
        help="folder of images, a quoted glob ('views/*.jpg'), or with "
        "--eye any stereo view source (folder of pairs, session)",
    )
    p.add_argument("-o", "--out", default="camera.yaml", help="camera YAML to write")
    p.add_argument(
        "--eye",
        choices=("left", "right"),
        help="take this eye of stereo views (" + NAMING_RULES + ")",
    )
    _layout_options(p)
    _solve_options(p)
    _gate_options(p, "min_views", "max_rms_px")
    _board_options(p)
    add_overwrite_option(p)
    add_config_option(p)
    p.set_defaults(func=run_camera)

    p = actions.add_parser(
        "stereo",
        help="calibrate the stereo pair from views",
        description="Calibrate the stereo pair; " + NAMING_RULES + "; or "
        "give --left 'GLOB' --right 'GLOB'. "
        "A result with an impossible baseline (or one far from a stated nominal "
        "baseline), a rectified principal point outside the image, a rectification "
        "keeping less than --min-rectified-fraction of the image or a high RMS is "
        "refused and nothing is written; the report lists every gate with its "
        "measured value, limit and verdict.",
    )
    p.add_argument(
        "source",
        nargs="?",
        help="folder of view pairs, an OpenCV image list (.xml/.yaml) or a session .h5",
    )
    p.add_argument(
        "--pairs",
        metavar="FILE.csv",
        dest="pairs_file",
        help="pairs listed in a CSV file, one 'left,right' line each (paths relative to it)",
    )
    p.add_argument(
        "--swap-eyes",
        action="store_true",
        help="exchange the eyes: the files labelled right are the left camera's",
    )
    _layout_options(p)
    p.add_argument(
        "--left",
        metavar="GLOB",
        dest="left_glob",
        help="left images (quoted glob), paired in sorted order with --right",
    )
    p.add_argument("--right", metavar="GLOB", dest="right_glob", help="right images (glob)")
    p.add_argument(
        "--intrinsics",
        nargs=2,
        metavar=("LEFT.yaml", "RIGHT.yaml"),
        help="fix the intrinsics to these 'calibrate camera' files",
    )
    p.add_argument("-o", "--out", default="calibration.yaml", help="calibration YAML to write")
    p.add_argument("--no-report", action="store_true", help="skip the PNG/HTML report")
    add_settle_option(p, "the calibration's path and its board ([calib])")
    p.add_argument(
        "--store-in", metavar="SESSION.h5", help="also store the calibration inside this session"
    )
    _solve_options(p)
    _gate_options(p, *_STEREO_GATES)
    _board_options(p)
    add_overwrite_option(p)
    add_config_option(p)
    p.set_defaults(func=run_stereo)

    p = actions.add_parser("export", help="write a calibration as ROS, Kalibr or OpenCV files")
    p.add_argument("calibration", help="calibration YAML (or session)")
    p.add_argument(
        "--format",
        required=True,
        choices=FORMATS,
        dest="fmt",
        help="ros: <stem>_left.yaml + <stem>_right.yaml camera_info; kalibr: "
        "<stem>-camchain.yaml; opencv: intrinsics.yml + extrinsics.yml",
    )
    p.add_argument("--out-dir", help="folder to write into (default: next to the calibration)")
    add_overwrite_option(p)
    p.set_defaults(func=run_export)

    p = actions.add_parser(
        "import",
        help="read another tool's stereo calibration",
        description="Read OpenCV's stereo sample files (M1 D1 M2 D2 R T, also "
        "K1 ...; YAML or XML; one file or intrinsics.yml extrinsics.yml), a "
        "Kalibr camchain, a ROS camera_info pair (left right) or a "
        "Middlebury calib.txt, check it with the sanity gates and write "
        "vbfe's calibration file.",
    )
    p.add_argument("files", nargs="+", metavar="FILE", help="the calibration file(s)")
    p.add_argument("-o", "--out", default="calibration.yaml", help="calibration YAML to write")
    p.add_argument(
        "--image-size",
        metavar="WxH",
        dest="image_size",
        help="image size, for OpenCV files that do not hold it, e.g. 640x480",
    )
    p.add_argument(
        "--unit-mm",
        type=positive(float),
        default=1000.0,
        metavar="MM",
        help="length of one unit of an OpenCV file's T, in mm (default 1000: metres; "
        "OpenCV's sample measures in board squares)",
    )
    _gate_options(p, *_RIG_GATES)
    add_overwrite_option(p)
    add_config_option(p)
    p.set_defaults(func=run_import)

    p = actions.add_parser("projector", help="calibrate the projector (Gray code on the board)")
    p.add_argument("captures", help="folder of pose_NNN/ Gray-code captures")
    p.add_argument("--calibration", required=True, help="stereo calibration YAML (or session)")
    p.add_argument(
        "-o", "--out", help="YAML to write (default: update --calibration, which needs --overwrite)"
    )
    p.add_argument(
        "--simulate",
        type=positive(int, zero=True),
        default=0,
        metavar="N",
        help="first capture N poses into CAPTURES with the rig's camera and projector "
        "(as projector-capture; rendered on the simulated bench)",
    )
    p.add_argument(
        "--seed", type=int, default=None, help="simulated bench: pose seed of the captures"
    )
    _board_options(p)
    add_overwrite_option(p)
    add_config_option(p)
    p.set_defaults(func=run_projector)

    p = actions.add_parser("check", help="go/no-go of the stored calibration")
    p.add_argument("stored", help="stored calibration YAML (or session)")
    p.add_argument("--against", help="a new calibration YAML to compare with")
    p.add_argument(
        "--views",
        help="folder of fresh view pairs (or a session); the board is the "
        "one stored in the calibration unless board options are given",
    )
    _gate_options(
        p,
        "working_distance_mm",
        "check_max_depth_error_mm",
        "check_max_epipolar_px",
        *_RIG_GATES,
    )
    _board_options(p)
    add_config_option(p)
    p.set_defaults(func=run_check)

    p = actions.add_parser("color", help="fit the colour crosstalk model (flat projections)")
    p.add_argument("calibration", help="calibration YAML to add color_mixing/color_offset to")
    p.add_argument(
        "-o",
        "--out",
        default=None,
        help="write here (default: update CALIBRATION in place, with --overwrite)",
    )
    p.add_argument("--frames", type=positive(int), default=3, help="frames averaged per projection")
    add_overwrite_option(p)
    add_config_option(p)
    p.set_defaults(func=run_color)


def _check_update(args: argparse.Namespace, inputs: list[str]) -> None:
    """A command that adds to a calibration: ``-o`` is a new file (never an input); without it
    the calibration YAML is updated in place, which replaces it (``--overwrite``)."""
    if args.out is None:
        check_outputs([args.calibration], inputs, args.overwrite)
    else:
        check_outputs([args.out], [*inputs, args.calibration], args.overwrite)


def run_board(args: argparse.Namespace) -> int:
    """Write the board files."""
    config, board = _config_and_board(args)
    check_outputs(
        [Path(args.out).with_suffix(".png"), Path(args.out).with_suffix(".pdf")],
        overwrite=args.overwrite,
    )
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
                bar.write(
                    f"{verdict.reason[:60]:<60} | "
                    f"{coverage_text(collector.coverage(), len(collector.pairs))}"
                )

        try:
            check_outputs([], directories=[args.folder], overwrite=True)  # adds new views only
            config, board = _config_and_board(args)
            result = commands.capture(
                config, args.folder, args.max_frames, args.seed, on_view, **board
            )
        finally:
            if preview is not None:
                preview.dispose()
    print(
        f"kept {len(result.names)} views of {result.frames_seen} frames in {result.folder}; "
        f"refused: {result.rejections or 'none'}"
    )
    print(
        "enough views for calibration"
        if result.enough
        else "not enough views yet: run capture again into the same folder with other poses"
    )
    return 0


_NAMED_CORNERS = 8  # rejected corners named one by one; the rest counted


def _print_solve_notes(dropped: dict[str, str], rejected: list, weak: str | None) -> None:
    """Dropped views and rejected corners by name (``rejected``: [view, camera, id, px] rows)."""
    for name, why in dropped.items():
        print(f"  dropped {name}: {why}")
    for view, camera, corner, px in rejected[:_NAMED_CORNERS]:
        eye = f" ({camera} eye)" if camera in ("left", "right") else ""
        print(
            f"  rejected corner {corner} of view {view}{eye}: {px:.2f} px from the fit, an outlier"
        )
    if len(rejected) > _NAMED_CORNERS:
        print(
            f"  rejected {len(rejected) - _NAMED_CORNERS} more outlier corners (listed in the "
            "calibration file)"
        )
    if weak:
        print(f"  {weak}")


def run_camera(args: argparse.Namespace) -> int:
    """Calibrate one camera and print intrinsics, σ and what was left out."""
    check_outputs([args.out], [args.source], args.overwrite)
    config, board = _config_and_board(args)
    with progress(desc="detecting corners", unit="image") as bar:
        result = commands.camera(
            config,
            args.source,
            args.out,
            args.eye,
            step=lambda: bar.update(1),
            settings=_settings(args),
            ext=args.ext,
            **board,
        )
    model = result.model
    K = model.K
    print(f"wrote {args.out}")
    _print_rows(
        [
            ("image size", f"{model.image_size[0]} x {model.image_size[1]} px"),
            ("fx, fy", f"{K[0, 0]:.2f}, {K[1, 1]:.2f} px"),
            ("cx, cy", f"{K[0, 2]:.2f}, {K[1, 2]:.2f} px"),
            ("distortion", ", ".join(f"{d:.5f}" for d in model.D)),
            (
                "RMS",
                f"{model.rms_px:.3f} px over {len(result.names)} views (per view "
                f"{model.per_view_rms_px.min():.3f} to {model.per_view_rms_px.max():.3f})",
            ),
            ("uncertainty", uncertainty_text(K, model.std_intrinsics)),
            *corner_rows(result.corners),
        ]
    )
    _print_solve_notes(
        result.dropped,
        [[r.view, r.camera, r.corner_id, r.residual_px] for r in result.fit.rejected],
        result.weak,
    )
    return 0


def _check_session_target(path: str) -> None:
    """``--store-in``: an existing session this process can read and write."""
    from vbfe.acquire import SessionReader

    if not Path(path).is_file():
        raise CalibrationError(f"--store-in {path}: no such session; give a recorded session")
    with SessionReader(path):
        pass
    if not os.access(path, os.W_OK):
        raise CalibrationError(f"--store-in {path}: the session is read-only; make it writable")


def run_stereo(args: argparse.Namespace) -> int:
    """Calibrate and print the summary; every destination is checked before the work."""
    out = Path(args.out)
    check_settle(args)
    reports = [] if args.no_report else [out.with_suffix(".png"), out.with_suffix(".html")]
    check_outputs(
        [out, *reports],
        [
            args.source,
            args.store_in,
            args.left_glob,
            args.right_glob,
            args.pairs_file,
            *(args.intrinsics or ()),
        ],
        args.overwrite,
    )
    if args.store_in is not None:
        _check_session_target(args.store_in)
    config, board = _config_and_board(args)
    intrinsics = tuple(args.intrinsics) if args.intrinsics else None
    with progress(desc="detecting corners", unit="view") as bar:
        outcome = commands.stereo(
            config,
            args.source,
            args.out,
            report=not args.no_report,
            store_in_session=args.store_in,
            step=lambda: bar.update(1),
            left_glob=args.left_glob,
            right_glob=args.right_glob,
            intrinsics=intrinsics,
            settings=_settings(args),
            ext=args.ext,
            pairs_file=args.pairs_file,
            swap_eyes=args.swap_eyes,
            **board,
        )
    result = outcome.result
    print(
        f"wrote {outcome.yaml_path}"
        + (f", report {outcome.report_paths[1]}" if outcome.report_paths else "")
    )
    _print_rows(summary_rows(result.calibration))
    print("  sanity gates:")
    for line in gate_lines(result.calibration):
        print(f"    {line}")
    for eye, fit in (("left", result.left), ("right", result.right)):
        print(
            f"  {eye} "
            + uncertainty_text(fit.K, fit.std_intrinsics)
            + (" (fixed from --intrinsics)" if intrinsics else "")
        )
    if result.renumbered:
        print(
            f"  the eyes numbered the chessboard from opposite ends in views "
            f"{', '.join(result.renumbered)}: the right eye's corners were renumbered to match"
        )
    unpaired = result.calibration.info["unpaired_files"]
    if unpaired:
        print(f"  left out {len(unpaired)} images without a partner: {', '.join(unpaired)}")
    _print_solve_notes(
        result.dropped, result.calibration.info["rejected_corners"], None
    )  # a weak result is noted in the summary rows
    settle_values(
        args,
        {
            "calib": {
                "calibration": str(Path(outcome.yaml_path).resolve()),
                **commands.board_spec(config, **board).calib_table(),
            }
        },
    )
    return 0


def run_export(args: argparse.Namespace) -> int:
    """Write the calibration in another tool's format."""
    targets = commands.export_targets(args.calibration, args.fmt, args.out_dir)
    folder = targets[0].parent
    check_outputs(
        [p for p in targets if p.parent.is_dir()],
        [args.calibration],
        args.overwrite,
        directories=[] if folder.is_dir() else [folder],
    )
    for path in commands.export(args.calibration, args.fmt, args.out_dir):
        print(f"wrote {path}")
    return 0


def run_import(args: argparse.Namespace) -> int:
    """Import another tool's calibration and print its summary."""
    check_outputs([args.out], args.files, args.overwrite)
    size = None
    if args.image_size is not None:
        m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", args.image_size)
        if not m:
            raise CalibrationError(
                f"--image-size {args.image_size!r}: give WIDTHxHEIGHT, e.g. 640x480"
            )
        size = (int(m[1]), int(m[2]))
    calibration, fmt = commands.import_files(
        rig_from(args), args.files, args.out, size, args.unit_mm, _settings(args)
    )
    print(f"read {fmt} calibration; wrote {args.out}")
    _print_rows(summary_rows(calibration))
    return 0


def run_projector_capture(args: argparse.Namespace) -> int:
    """Capture Gray-code poses, saying what the capture waits for."""
    check_outputs([], directories=[args.out], overwrite=True)  # adds poses after those there
    with progress(total=args.poses, desc="poses", unit="pose") as bar:

        def on_event(message: str) -> None:
            bar.write(message)
            if message.startswith("kept"):
                bar.update(1)

        written = commands.projector_capture(
            rig_from(args), args.out, args.poses, args.seed, on_event
        )
    print(
        f"wrote {len(written)} poses into {args.out}; calibrate with "
        f"'vbfe calibrate projector {args.out} --calibration CALIBRATION.yaml'"
    )
    return 0


def run_projector(args: argparse.Namespace) -> int:
    """Calibrate the projector and print its intrinsics (without -o: update --calibration)."""
    _check_update(args, [args.captures])
    with progress(total=1, desc="projector calibration") as bar:
        config, board = _config_and_board(args)
        calibration = commands.projector(
            config, args.captures, args.calibration, args.out, args.simulate, args.seed, **board
        )
        bar.update(1)
    K, T = calibration.K_proj, calibration.T_proj
    assert K is not None and T is not None  # set by the projector calibration
    print(
        f"projector fx={K[0, 0]:.2f} fy={K[1, 1]:.2f} cx={K[0, 2]:.2f} cy={K[1, 2]:.2f} px, "
        f"RMS {calibration.rms_projector_px:.3f} px; T (left->projector) = "
        f"{', '.join(f'{v * 1e3:.2f}' for v in T)} mm; "
        f"wrote {args.out or args.calibration}"
    )
    return 0


def run_check(args: argparse.Namespace) -> int:
    """Print the comparison; exit 1 on NO-GO."""
    with progress(total=1, desc="checking") as bar:
        config, board = _config_and_board(args)
        result = commands.check(
            config, args.stored, args.against, args.views, settings=_settings(args), **board
        )
        bar.update(1)
    _print_rows(result.rows())
    return 0 if result.passed else 1


def run_color(args: argparse.Namespace) -> int:
    """Project flat colours, fit the crosstalk model and store it in the calibration."""
    from vbfe.acquire import frame_feed
    from vbfe.calib import load_calibration
    from vbfe.drivers.registry import open_rig
    from vbfe.recon.color import capture_color_model

    _check_update(args, [])
    calibration = load_calibration(args.calibration)
    settle_s = rig_from(args).calib.projector_settle_s
    rig = open_rig(rig_from(args), families=("camera", "projector"))
    with frame_feed(rig) as frames:
        model = capture_color_model(frames, rig.projector, frames=args.frames, settle_s=settle_s)
    out = model.apply_to(calibration).save(args.out or args.calibration)
    rows = "; ".join(" ".join(f"{v:.3f}" for v in row) for row in model.mixing)
    print(
        f"colour mixing (camera BGR <- projector BGR) [{rows}], offset "
        f"{' '.join(f'{v:.1f}' for v in model.offset)}; wrote {out}"
    )
    return 0
