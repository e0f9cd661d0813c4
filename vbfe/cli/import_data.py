"""`vbfe import`: external point clouds or depth images + a force CSV → a clouds file to train
on; a robot's bag (MCAP, rosbag2, ROS 1) → a session."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from vbfe.cli.common import LazyProgress, positive
from vbfe.cli.outputs import add_overwrite_option, check_outputs


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `import` subcommand."""
    parser = sub.add_parser(
        "import",
        help="import external clouds or depth images with a force CSV, or a bag",
        description="Turn a folder of frames (KIND clouds: *.ply/*.npy point clouds in metres; "
        "KIND depth: 16-bit PNG depth images) and a force CSV into OUT.clouds.h5, which "
        "`vbfe train` and `vbfe evaluate` take like a reconstructed session (see "
        "docs/how-to/import.md); or (KIND bag) a ROS bag — MCAP file, rosbag2 folder or ROS 1 "
        ".bag — into a session OUT.h5 (see docs/how-to/export-mcap.md).",
    )
    parser.add_argument("kind", choices=("clouds", "depth", "bag"), help="what the input is")
    parser.add_argument(
        "frames",
        metavar="FOLDER|BAG",
        help="frame files, in natural order of their names (data2 before data10); or the bag",
    )
    parser.add_argument(
        "--forces",
        type=Path,
        metavar="TABLE",
        help="force table (clouds, depth): CSV with a header row, or headerless "
        "columns separated by commas or whitespace",
    )
    parser.add_argument(
        "--out",
        "-o",
        required=True,
        metavar="OUT.clouds.h5|OUT.h5",
        help="the file to write: OUT.clouds.h5 for clouds and depth, a session OUT.h5 for a bag",
    )
    parser.add_argument(
        "--force-columns",
        metavar="FX,FY,FZ",
        help="one or three force columns, by name or number (0 = first; clouds, depth)",
    )
    parser.add_argument("--force-unit", default="N", help="N (default), mN, kN, gf, kgf, lbf")
    parser.add_argument(
        "--force-scale",
        type=float,
        default=1.0,
        metavar="FACTOR",
        help="multiply the forces by FACTOR (e.g. sensor counts to the unit, "
        "-1 to flip the sign; default 1)",
    )
    parser.add_argument(
        "--force-axis",
        default="z",
        choices=("x", "y", "z"),
        help="axis a single force column is stored on (default z)",
    )
    key = parser.add_mutually_exclusive_group()
    key.add_argument("--time-column", help="column of force sample times")
    key.add_argument(
        "--frame-column",
        help="column of frame indices (0 = first file); "
        "with neither, row i of the table is frame i",
    )
    parser.add_argument(
        "--time-unit", default="s", help="s (default), ms, us or ns, for the force and frame times"
    )
    parser.add_argument("--fps", type=positive(float), help="frame i is at i / FPS seconds")
    parser.add_argument(
        "--frame-times",
        type=Path,
        metavar="TABLE",
        help="table (like --forces) with one time per frame file, on the forces' clock",
    )
    parser.add_argument("--frame-time-column", help="column of --frame-times (name or number)")
    parser.add_argument("--condition", help="label of the recording's condition in reports")
    parser.add_argument(
        "--min-depth",
        type=float,
        default=-math.inf,
        metavar="M",
        help="drop points nearer than M metres (z)",
    )
    parser.add_argument(
        "--max-depth",
        type=float,
        default=math.inf,
        metavar="M",
        help="drop points farther than M metres (z)",
    )
    depth = parser.add_argument_group("depth images")
    for name in ("fx", "fy", "cx", "cy"):
        depth.add_argument(f"--{name}", type=float, help="intrinsics, pixels")
    depth.add_argument(
        "--depth-scale",
        type=positive(float),
        metavar="M_PER_UNIT",
        help="metres per depth unit (e.g. 0.001 for millimetres)",
    )
    depth.add_argument(
        "--roi",
        type=int,
        nargs=4,
        metavar=("X0", "Y0", "X1", "Y1"),
        help="pixel region of interest (X1, Y1 exclusive)",
    )
    depth.add_argument("--pixel-step", type=positive(int), default=1, help="use every k-th pixel")
    depth.add_argument(
        "--crop-origin",
        type=int,
        nargs=2,
        metavar=("X", "Y"),
        help="the images are crops of the camera's image starting at pixel "
        "(X, Y); --cx/--cy stay the camera's (may lie outside the crop)",
    )
    bag = parser.add_argument_group("bags (topics found by type and name when not given)")
    bag.add_argument("--left", metavar="TOPIC", help="left image topic (Image or CompressedImage)")
    bag.add_argument("--right", metavar="TOPIC", help="right image topic")
    bag.add_argument("--image", metavar="TOPIC", help="one topic with both eyes side by side")
    bag.add_argument(
        "--force", metavar="TOPIC", help="WrenchStamped, Wrench or Vector3Stamped topic"
    )
    bag.add_argument(
        "--left-info", metavar="TOPIC", help="left camera_info (default: beside the image topic)"
    )
    bag.add_argument("--right-info", metavar="TOPIC", help="right camera_info")
    bag.add_argument(
        "--pair-tolerance-ms",
        type=float,
        default=5.0,
        help="left and right stamps closer than this make a frame (default 5)",
    )
    add_overwrite_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Import and print what was written."""
    if args.kind == "bag":
        return run_bag(args)
    from vbfe.common.errors import EstimateError

    missing = [
        flag
        for flag, value in (("--forces", args.forces), ("--force-columns", args.force_columns))
        if not value
    ]
    if missing:
        raise EstimateError(f"{args.kind} frames need {', '.join(missing)}")
    from vbfe.estimate.importing import DepthCamera, ForceTable, import_frames

    check_outputs(
        [args.out], [args.frames, args.forces, args.frame_times], args.overwrite, writes="hdf5"
    )
    camera = None
    if args.kind == "depth":
        needed = {
            "--fx": args.fx,
            "--fy": args.fy,
            "--cx": args.cx,
            "--cy": args.cy,
            "--depth-scale": args.depth_scale,
        }
        missing = [flag for flag, value in needed.items() if value is None]
        if missing:
            raise EstimateError(f"depth frames need {' '.join(missing)}")
        camera = DepthCamera(
            args.fx,
            args.fy,
            args.cx,
            args.cy,
            args.depth_scale,
            tuple(args.roi) if args.roi else None,
            args.pixel_step,
            tuple(args.crop_origin) if args.crop_origin else None,
        )
    forces = ForceTable(
        args.forces,
        tuple(c.strip() for c in args.force_columns.split(",")),
        args.force_unit,
        args.time_column,
        args.time_unit,
        args.frame_column,
        args.force_axis,
        args.force_scale,
    )
    path, n_frames, with_force = import_frames(
        args.kind,
        args.frames,
        args.out,
        forces,
        fps=args.fps,
        frame_times_csv=args.frame_times,
        frame_time_column=args.frame_time_column,
        camera=camera,
        condition=args.condition,
        depth_range_m=(args.min_depth, args.max_depth),
        overwrite=args.overwrite,
    )
    if args.time_column is None and args.frame_column is None:
        print(f"forces: row i of {args.forces.name} is frame i")
    print(f"wrote {path}: {n_frames} frames, {with_force} with a force")
    if with_force < n_frames:
        print(
            f"{n_frames - with_force} frames have no force (outside the force record) and "
            "will be skipped in training"
        )
    return 0


def run_bag(args: argparse.Namespace) -> int:
    """Import a bag as a session and print what was written."""
    from vbfe.bags.importing import TopicChoice, import_bag

    check_outputs([args.out], [args.frames], args.overwrite, writes="session")
    given = TopicChoice(
        args.left,
        args.right,
        args.image,
        args.force,
        args.left_info,
        args.right_info,
        args.pair_tolerance_ms / 1e3,
    )
    with LazyProgress("import", "frame") as on_progress:
        summary = import_bag(args.frames, args.out, given, on_progress)
    print(
        f"wrote {summary.path}: {summary.frames} stereo frames, {summary.forces} force "
        f"samples; calibration: {summary.calibration}"
    )
    print("topics: " + ", ".join(f"{k} {v}" for k, v in summary.topics.items()))
    if summary.unpaired_images:
        print(
            f"{summary.unpaired_images} images had no partner within "
            f"{args.pair_tolerance_ms:g} ms and were left out"
        )
    return 0
