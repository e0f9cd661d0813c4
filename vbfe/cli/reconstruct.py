"""`vbfe reconstruct`: point clouds of recorded sessions, one image pair or a folder of pairs."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from vbfe.cli.batch_options import add_batch_options, batch_settings, run_batch
from vbfe.cli.common import add_config_option, config_from, progress
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.config import section

SESSION_SUFFIXES = (".h5", ".hdf5")


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `reconstruct` subcommand."""
    parser = sub.add_parser(
        "reconstruct", help="structured-light stereo point clouds of sessions or image pairs",
        description="Rectify, match (SGBM + De Bruijn verification) and triangulate every frame "
        "of SESSION.h5 into SESSION.clouds.h5 next to it, or of image pairs: LEFT RIGHT files, "
        "or a FOLDER of <name>_left/<name>_right, left<name>/right<name> or left/ + right/ "
        "images. Several sessions or a manifest CSV (vbfe dataset) run one task per session "
        "on a local process pool or a Ray cluster; sessions whose clouds are current are "
        "skipped. Where the De Bruijn pattern cannot be read, SGBM's matches are kept and flagged "
        "unverified (per point in the clouds file, per pixel in the quality map).")
    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="SESSION.h5 (one or more), MANIFEST.csv, LEFT RIGHT image files, "
                        "or a FOLDER of pairs")
    parser.add_argument("--calib", metavar="FILE", default=None,
                        help="calibration YAML (default: the one stored in each session)")
    rectified = parser.add_argument_group(
        "already-rectified pairs", "instead of --calib: the rectified pair's geometry")
    rectified.add_argument("--rectified", action="store_true",
                           help="the images are rectified and undistorted")
    rectified.add_argument("--f", type=float, metavar="PX", help="focal length (px)")
    rectified.add_argument("--baseline", type=float, metavar="MM", help="baseline (mm)")
    rectified.add_argument("--cx", type=float, metavar="PX", help="principal point x (px)")
    rectified.add_argument("--cy", type=float, metavar="PX", help="principal point y (px)")
    rectified.add_argument("--doffs", type=float, default=0.0, metavar="PX",
                           help="right principal point x minus the left's (px; Middlebury's "
                                "doffs; default 0)")
    parser.add_argument("--out", metavar="CLOUDS.h5", default=None,
                        help="output file of one input (default: next to it, .clouds.h5)")
    parser.add_argument("--workers", type=int, default=None,
                        help="parallel processes: frames of one input, or sessions of many "
                        "(default: one per CPU core)")
    parser.add_argument("--no-verify", action="store_true",
                        help="skip the De Bruijn verification (bare SGBM; for pairs without "
                        "the projected pattern)")
    parser.add_argument("--ply-dir", metavar="DIR", default=None,
                        help="also write one PLY file per frame into DIR (one input)")
    parser.add_argument("--maps-dir", metavar="DIR", default=None,
                        help="also write disparity, depth and quality maps per frame into DIR "
                        "(one input)")
    parser.add_argument("--maps-format", choices=("png", "npy"), default="png",
                        help="png: 16-bit, disparity px = value/256, depth mm = value/10; "
                        "npy: float32 px and m (default: png)")
    add_batch_options(parser)
    add_overwrite_option(parser)
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
        return rectified_calibration(args.f, args.baseline, args.cx, args.cy, size, args.doffs)
    if size is not None and args.calib is None:
        raise ReconError("image pairs need --calib calib.yaml, or --rectified with --f, "
                         "--baseline, --cx and --cy")
    return resolve_calibration(args.inputs[0], args.calib)


def _is_batch(args: argparse.Namespace) -> bool:
    kinds = {Path(i).suffix.lower() for i in args.inputs}
    return bool(kinds) and kinds <= {*SESSION_SUFFIXES, ".csv"} and (
        len(args.inputs) > 1 or ".csv" in kinds or args.executor is not None)


def _run_batch(args: argparse.Namespace, config: dict, params: object, settings: object) -> int:
    from vbfe.batch.errors import BatchError
    from vbfe.batch.manifest import expand_sessions
    from vbfe.batch.tasks import ReconstructTask

    if args.out or args.ply_dir or args.maps_dir or args.rectified:
        raise BatchError("--out, --ply-dir, --maps-dir and --rectified take one input; with "
                         "several sessions each one's clouds go next to it")
    executor, address = batch_settings(args, config.get("batch", {}))
    task = ReconstructTask(sgbm=dataclasses.asdict(params), verify=not args.no_verify,
                           settings=dataclasses.asdict(settings), calibration=args.calib,
                           overwrite=args.overwrite)
    run_batch(task, expand_sessions(args.inputs), executor, args.workers, address,
              "reconstruct", lambda v: v["action"] + (f", {v['summary']}" if "summary" in v
                                                      else ""))
    return 0


def run(args: argparse.Namespace) -> int:
    """Reconstruct, print the quality summary and warnings, and say where the clouds went."""
    from vbfe.recon.clouds import CloudReader, export_ply, sidecar_path
    from vbfe.recon.inputs import image_pairs
    from vbfe.recon.maps import MapOutput
    from vbfe.recon.matching import SgbmParams
    from vbfe.recon.quality import ReconSettings, quality_warnings, summary_line
    from vbfe.recon.session_recon import reconstruct_images, reconstruct_session

    config = config_from(args)
    params = SgbmParams.from_config(section(config, "sgbm"))
    settings = ReconSettings.from_config(section(config, "recon"))
    if _is_batch(args):
        return _run_batch(args, config, params, settings)
    maps = MapOutput(Path(args.maps_dir), args.maps_format) if args.maps_dir else None
    common = {"out_path": args.out, "workers": args.workers, "sgbm_params": params,
              "verify": not args.no_verify, "settings": settings, "maps": maps}
    session = len(args.inputs) == 1 and Path(args.inputs[0]).suffix.lower() in SESSION_SUFFIXES
    if session:
        from vbfe.acquire import SessionReader

        source = args.inputs[0]
        check_outputs([args.out or sidecar_path(source)], [source, args.calib],
                      args.overwrite, directories=[args.ply_dir, args.maps_dir])
        calibration = _calibration(args, None)
        with SessionReader(source) as reader:
            n_frames = reader.n_frames
            if reader.growing:
                print(f"vbfe reconstruct: {source} is still being recorded: reconstructing its "
                      f"{n_frames} frames flushed so far (the output is marked partial)",
                      file=sys.stderr)
        with progress(total=n_frames, desc="reconstruct", unit="frame") as bar:
            out = reconstruct_session(source, calibration=calibration, progress=bar.update,
                                      **common)
    else:
        pairs = image_pairs(args.inputs)
        check_outputs([args.out or sidecar_path(pairs.lefts[0])],
                      [*pairs.lefts, *pairs.rights, args.calib], args.overwrite,
                      directories=[args.ply_dir, args.maps_dir])
        calibration = _calibration(args, pairs.frame_size())
        with progress(total=pairs.n_frames, desc="reconstruct", unit="pair") as bar:
            out = reconstruct_images(pairs, calibration, progress=bar.update, **common)
    with CloudReader(out) as clouds:
        print(summary_line(clouds))
        warnings = quality_warnings(clouds, settings)
    for warning in warnings:
        print(f"vbfe reconstruct: warning: {warning}", file=sys.stderr)
    if maps is not None:
        print(f"disparity and depth maps ({maps.fmt}) in {maps.folder}")
    if args.ply_dir:
        files = export_ply(out, args.ply_dir)
        print(f"{len(files)} PLY files in {args.ply_dir}")
    return 0
