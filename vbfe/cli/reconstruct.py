"""`vbfe reconstruct`: point clouds of a recorded session, one image pair or a folder of pairs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vbfe.cli.common import add_config_option, config_from, progress
from vbfe.config import section


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `reconstruct` subcommand."""
    parser = sub.add_parser(
        "reconstruct", help="structured-light stereo point clouds of a session or image pairs",
        description="Rectify, match (SGBM + De Bruijn verification) and triangulate every frame "
        "of SESSION.h5 into SESSION.clouds.h5 next to it, or of image pairs: LEFT RIGHT files, "
        "or a FOLDER of <name>_left/<name>_right, left<name>/right<name> or left/ + right/ "
        "images. Exit status 1 when the pattern was too weak for verification.")
    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="SESSION.h5, LEFT RIGHT image files, or a FOLDER of pairs")
    parser.add_argument("--calib", metavar="FILE", default=None,
                        help="calibration YAML (default: the one stored in the session)")
    rectified = parser.add_argument_group(
        "already-rectified pairs", "instead of --calib: the rectified pair's geometry")
    rectified.add_argument("--rectified", action="store_true",
                           help="the images are rectified and undistorted")
    rectified.add_argument("--f", type=float, metavar="PX", help="focal length (px)")
    rectified.add_argument("--baseline", type=float, metavar="MM", help="baseline (mm)")
    rectified.add_argument("--cx", type=float, metavar="PX", help="principal point x (px)")
    rectified.add_argument("--cy", type=float, metavar="PX", help="principal point y (px)")
    parser.add_argument("--out", metavar="CLOUDS.h5", default=None,
                        help="output file (default: next to the input, .clouds.h5)")
    parser.add_argument("--workers", type=int, default=None,
                        help="parallel processes (default: one per CPU core)")
    parser.add_argument("--no-verify", action="store_true",
                        help="skip the De Bruijn verification (bare SGBM; for pairs without "
                        "the projected pattern)")
    parser.add_argument("--ply-dir", metavar="DIR", default=None,
                        help="also write one PLY file per frame into DIR")
    parser.add_argument("--maps-dir", metavar="DIR", default=None,
                        help="also write disparity and depth maps per frame into DIR")
    parser.add_argument("--maps-format", choices=("png", "npy"), default="png",
                        help="png: 16-bit, disparity px = value/256, depth mm = value/10; "
                        "npy: float32 px and m (default: png)")
    add_config_option(parser)
    parser.set_defaults(func=run)


def _calibration(args: argparse.Namespace, size: tuple[int, int] | None):
    """The calibration from --calib, --rectified geometry or (sessions) the stored one."""
    from vbfe.recon.errors import ReconError
    from vbfe.recon.inputs import rectified_calibration
    from vbfe.recon.session_recon import resolve_calibration

    if args.rectified:
        missing = [f"--{name}" for name in ("f", "baseline", "cx", "cy")
                   if getattr(args, name) is None]
        if missing or args.calib:
            raise ReconError("--rectified needs --f, --baseline, --cx and --cy (missing "
                             f"{', '.join(missing) or 'none'}) and no --calib")
        if size is None:
            raise ReconError("--rectified is for image pairs; a session stores its calibration")
        return rectified_calibration(args.f, args.baseline, args.cx, args.cy, size)
    if size is not None and args.calib is None:
        raise ReconError("image pairs need --calib calib.yaml, or --rectified with --f, "
                         "--baseline, --cx and --cy")
    return resolve_calibration(args.inputs[0], args.calib)


def run(args: argparse.Namespace) -> int:
    """Reconstruct, print the quality summary and warnings, and say where the clouds went."""
    from vbfe.recon.clouds import CloudReader, export_ply
    from vbfe.recon.inputs import image_pairs
    from vbfe.recon.maps import MapOutput
    from vbfe.recon.matching import SgbmParams
    from vbfe.recon.quality import ReconSettings, quality_warnings, summary_line
    from vbfe.recon.session_recon import reconstruct_images, reconstruct_session

    config = config_from(args)
    params = SgbmParams.from_config(section(config, "sgbm"))
    settings = ReconSettings.from_config(section(config, "recon"))
    maps = MapOutput(Path(args.maps_dir), args.maps_format) if args.maps_dir else None
    common = {"out_path": args.out, "workers": args.workers, "sgbm_params": params,
              "verify": not args.no_verify, "settings": settings, "maps": maps}
    session = len(args.inputs) == 1 and Path(args.inputs[0]).suffix.lower() in (".h5", ".hdf5")
    if session:
        from vbfe.acquire import SessionReader

        calibration = _calibration(args, None)
        with SessionReader(args.inputs[0]) as reader:
            n_frames = reader.n_frames
        with progress(total=n_frames, desc="reconstruct", unit="frame") as bar:
            out = reconstruct_session(args.inputs[0], calibration=calibration,
                                      progress=bar.update, **common)
    else:
        pairs = image_pairs(args.inputs)
        calibration = _calibration(args, pairs.frame_size())
        with progress(total=pairs.n_frames, desc="reconstruct", unit="pair") as bar:
            out = reconstruct_images(pairs, calibration, progress=bar.update, **common)
    with CloudReader(out) as clouds:
        print(summary_line(clouds))
        warnings, pattern_missing = quality_warnings(clouds, settings)
    for warning in warnings:
        print(f"vbfe reconstruct: warning: {warning}", file=sys.stderr)
    if maps is not None:
        print(f"disparity and depth maps ({maps.fmt}) in {maps.folder}")
    if args.ply_dir:
        files = export_ply(out, args.ply_dir)
        print(f"{len(files)} PLY files in {args.ply_dir}")
    return 1 if pattern_missing else 0
