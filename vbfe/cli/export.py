"""`vbfe export`: a session as MCAP with ROS 2 messages (Foxglove, Rerun, ROS 2 tools)."""

from __future__ import annotations

import argparse

from vbfe.cli.common import LazyProgress
from vbfe.cli.outputs import add_session_output_options, session_and_output


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `export` subcommand."""
    parser = sub.add_parser(
        "export",
        help="write a session as MCAP (ROS 2 messages) for Foxglove, Rerun, ROS 2",
        description="Write every stream of SESSION.h5 as ROS 2 messages into one MCAP file: "
        "images (as --images says: lossless PNG, JPEG or raw; an mjpeg session's own JPEG "
        "bytes unless raw), "
        "camera_info from the stored calibration, the trocar as WrenchStamped, point clouds "
        "from a clouds file, projector events, gaps and live estimates; Unix timestamps from "
        "the session's clock pairs. See docs/how-to/export-mcap.md. (`vbfe calibrate export` "
        "writes a calibration alone as ROS / Kalibr / OpenCV files.)",
    )
    add_session_output_options(
        parser, ".mcap", "output file", "also write these point clouds as sensor_msgs/PointCloud2"
    )
    parser.add_argument(
        "--format",
        choices=("mcap",),
        default="mcap",
        help="output format (mcap, the rosbag2 default)",
    )
    parser.add_argument(
        "--compression",
        choices=("lz4", "zstd"),
        default="lz4",
        help="chunk compression: lz4 (default, fast) or zstd (smaller files, about twice the time)",
    )
    parser.add_argument(
        "--images",
        default="png",
        metavar="png|jpeg[:QUALITY]|raw",
        help="how images are written: png (default, lossless sensor_msgs/CompressedImage), "
        "jpeg[:QUALITY] (lossy CompressedImage, quality 1-100, default 90), raw "
        "(sensor_msgs/Image bgr8, the largest)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Export and print what was written."""
    from vbfe.bags.export import export_mcap
    from vbfe.messages.images import image_codec

    images = image_codec(args.images)
    session, out = session_and_output(args, ".mcap")
    with LazyProgress("export", "frame") as on_progress:
        summary = export_mcap(session, out, args.clouds, args.compression, on_progress, images)
    topics = ", ".join(f"{topic} {n}" for topic, n in sorted(summary.messages.items()))
    print(
        f"wrote {summary.path}: {sum(summary.messages.values())} messages over "
        f"{(summary.end_ns - summary.start_ns) / 1e9:.2f} s ({topics})"
    )
    return 0
