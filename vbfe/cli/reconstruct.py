"""`vbfe reconstruct`: point clouds of recorded sessions, one image pair or a folder of pairs."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

from vbfe.cli.batch_options import add_batch_options, batch_settings, run_batch
from vbfe.cli.common import LazyProgress, add_config_option, positive, rig_from
from vbfe.cli.outputs import add_overwrite_option, check_outputs

if TYPE_CHECKING:
    from vbfe.recon import SgbmParams
    from vbfe.recon.quality import ReconSettings

SESSION_SUFFIXES = (".h5", ".hdf5")


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `reconstruct` subcommand."""
    parser = sub.add_parser(
        "reconstruct",
        help="structured-light stereo point clouds of sessions or image pairs",
        description="Rectify, match (SGBM + De Bruijn verification) and triangulate every frame "
        "of SESSION.h5 into SESSION.clouds.h5 next to it, or of image pairs: LEFT RIGHT files, "
        "or a FOLDER of <name>_left/<name>_right, left<name>/right<name> or left/ + right/ "
        "images. Several sessions or a manifest CSV (vbfe dataset) run one task per session "
        "on a local process pool or a Ray cluster; sessions whose clouds are current are "
        "skipped. Where the De Bruijn pattern cannot be read, SGBM's matches are kept and flagged "
        "unverified (per point in the clouds file, per pixel in the quality map).",
    )
    parser.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="SESSION.h5 (one or more), MANIFEST.csv, LEFT RIGHT image files, or a FOLDER of pairs",
    )
    parser.add_argument(
        "--calib",
        metavar="FILE",
        default=None,
        help="calibration YAML, or a Middlebury calib.txt for rectified pairs "
        "(default: the one stored in each session)",
    )
    rectified = parser.add_argument_group(
        "already-rectified pairs", "instead of --calib: the rectified pair's geometry"
    )
    rectified.add_argument(
        "--rectified", action="store_true", help="the images are rectified and undistorted"
    )
    rectified.add_argument("--f", type=float, metavar="PX", help="focal length (px; fx = fy)")
    rectified.add_argument("--fx", type=float, metavar="PX", help="horizontal focal length (px)")
    rectified.add_argument("--fy", type=float, metavar="PX", help="vertical focal length (px)")
    rectified.add_argument("--baseline", type=float, metavar="MM", help="baseline (mm)")
    rectified.add_argument("--cx", type=float, metavar="PX", help="principal point x (px)")
    rectified.add_argument("--cy", type=float, metavar="PX", help="principal point y (px)")
    rectified.add_argument(
        "--doffs",
        type=float,
        default=0.0,
        metavar="PX",
        help="right principal point x minus the left's (px; Middlebury's doffs; default 0)",
    )
    matching = parser.add_argument_group(
        "disparity range", "instead of the range derived from [recon] min_depth_mm/max_depth_mm"
    )
    matching.add_argument(
        "--min-disparity",
        type=int,
        metavar="PX",
        default=None,
        help="smallest disparity searched (px; [sgbm] min_disparity)",
    )
    matching.add_argument(
        "--num-disparities",
        type=int,
        metavar="N",
        default=None,
        help="number of disparities searched, a multiple of 16 ([sgbm] num_disparities)",
    )
    parser.add_argument(
        "--out",
        metavar="CLOUDS.h5",
        default=None,
        help="output file of one input (default: next to it, .clouds.h5)",
    )
    parser.add_argument(
        "--workers",
        type=positive(int),
        default=None,
        help="parallel processes: frames of one input, or sessions of many "
        "(default: one per CPU core)",
    )
    parser.add_argument(
        "--no-verify",
        action="store_true",
        help="skip the De Bruijn verification (bare SGBM; for pairs without the projected pattern)",
    )
    parser.add_argument(
        "--ply-dir",
        metavar="DIR",
        default=None,
        help="also write one PLY file per frame into DIR (one input)",
    )
    parser.add_argument(
        "--maps-dir",
        metavar="DIR",
        default=None,
        help="also write disparity, depth and quality maps per frame into DIR (one input)",
    )
    parser.add_argument(
        "--maps-format",
        choices=("png", "npy"),
        default="png",
        help="png: 16-bit, disparity px = value/256, depth mm = value/10; "
        "npy: float32 px and m (default: png)",
    )
    truth = parser.add_argument_group(
        "ground truth",
        "score the disparity of one pair against a truth map (Middlebury "
        "evaluation: density, bad>1/2/3 px, mean absolute error in px and mm)",
    )
    truth.add_argument(
        "--truth",
        metavar="GT",
        default=None,
        help="truth map of the left view: Middlebury PFM (inf = unknown) or an "
        "8/16-bit PNG (0 = unknown)",
    )
    truth.add_argument(
        "--truth-kind",
        choices=("disparity", "depth"),
        default="disparity",
        help="what the truth holds: disparity (px) or depth (mm) (default: disparity)",
    )
    truth.add_argument(
        "--truth-scale",
        type=float,
        default=None,
        metavar="S",
        help="PNG value per px of disparity or per mm of depth (default: 256 "
        "for 16-bit disparity, 10 for 16-bit depth; 8-bit maps need it, e.g. 4 "
        "for Middlebury 2003 quarter size)",
    )
    add_batch_options(parser)
    add_overwrite_option(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def _rectified(args: argparse.Namespace) -> dict[str, float] | None:
    """The --rectified geometry (None without --rectified)."""
    from vbfe.common.errors import ReconError

    if not args.rectified:
        return None
    fx, fy = (args.fx, args.fy) if args.f is None else (args.f, args.f)
    missing = [
        flag
        for flag, value in (
            ("--f (or --fx and --fy)", fx if fy else None),
            ("--baseline", args.baseline),
            ("--cx", args.cx),
            ("--cy", args.cy),
        )
        if value is None
    ]
    if missing or (args.f is not None and (args.fx or args.fy)):
        raise ReconError(
            "--rectified needs --f (or --fx and --fy), --baseline, --cx and "
            f"--cy (missing {', '.join(missing) or 'none'}), not both --f and "
            "--fx/--fy"
        )
    return {
        "fx_px": fx,
        "fy_px": fy,
        "baseline_mm": args.baseline,
        "cx": args.cx,
        "cy": args.cy,
        "doffs_px": args.doffs,
    }


def _range_flags(args: argparse.Namespace) -> dict[str, int]:
    """The [sgbm] keys set by --min-disparity/--num-disparities."""
    from vbfe.common.errors import ReconError

    if args.min_disparity is not None and args.num_disparities is None:
        raise ReconError(
            "--min-disparity needs --num-disparities (without it the range comes "
            "from [recon] min_depth_mm/max_depth_mm)"
        )
    return {
        key: value
        for key, value in (
            ("min_disparity", args.min_disparity),
            ("num_disparities", args.num_disparities),
        )
        if value is not None
    }


def _is_batch(args: argparse.Namespace) -> bool:
    kinds = {Path(i).suffix.lower() for i in args.inputs}
    return (
        bool(kinds)
        and kinds <= {*SESSION_SUFFIXES, ".csv"}
        and (len(args.inputs) > 1 or ".csv" in kinds or args.executor is not None)
    )


def _run_batch(
    args: argparse.Namespace, config: dict, params: SgbmParams, settings: ReconSettings
) -> int:
    from vbfe.batch.manifest import expand_sessions
    from vbfe.batch.tasks import ReconstructTask
    from vbfe.common.errors import BatchError

    if args.out or args.ply_dir or args.maps_dir or args.rectified or args.truth:
        raise BatchError(
            "--out, --ply-dir, --maps-dir, --rectified and --truth take one "
            "input; with several sessions each one's clouds go next to it"
        )
    executor, address = batch_settings(args, rig_from(args).batch)
    task = ReconstructTask(
        sgbm=dataclasses.asdict(params),
        verify=not args.no_verify,
        settings=dataclasses.asdict(settings),
        calibration=args.calib,
        overwrite=args.overwrite,
    )
    run_batch(
        task,
        expand_sessions(args.inputs),
        executor,
        args.workers,
        address,
        "reconstruct",
        lambda v: v["action"] + (f", {v['summary']}" if "summary" in v else ""),
    )
    return 0


class _LazyBar(LazyProgress):
    """The reconstruction's bar, opened once the work starts (nothing on stderr before a
    refusal), saying when the session is still being recorded."""

    def __init__(self, unit: str, source: str) -> None:
        super().__init__("reconstruct", unit)
        self.source, self._done = source, 0

    def start(self, total: int, partial: bool) -> None:
        self(0, total)
        if partial:
            tqdm.write(
                f"vbfe reconstruct: {self.source} is still being recorded: "
                f"reconstructing its {total} frames flushed so far (the output is "
                "marked partial)",
                file=sys.stderr,
            )

    def update(self, n: int) -> None:
        self._done += n
        self(self._done)


def run(args: argparse.Namespace) -> int:
    """Reconstruct, print the quality summary, warnings and truth scores, and say where the
    clouds went."""
    from vbfe.common.errors import ReconError
    from vbfe.recon import CloudReader, SgbmParams, export_ply, sidecar_path
    from vbfe.recon.inputs import image_pairs, pair_calibration
    from vbfe.recon.maps import MapOutput
    from vbfe.recon.quality import quality_warnings, summary_line
    from vbfe.recon.scoring import score_disparity, truth_disparity
    from vbfe.recon.session_recon import reconstruct_images, reconstruct_session

    rig = rig_from(args)
    flags = _range_flags(args)
    params = SgbmParams.from_config({**rig.tables["sgbm"], **flags}) if flags else rig.sgbm
    settings, config = rig.recon, rig.tables
    if _is_batch(args):
        return _run_batch(args, config, params, settings)
    maps = MapOutput(Path(args.maps_dir), args.maps_format) if args.maps_dir else None
    common = {
        "out_path": args.out,
        "workers": args.workers,
        "sgbm_params": params,
        "verify": not args.no_verify,
        "settings": settings,
        "maps": maps,
    }
    session = len(args.inputs) == 1 and Path(args.inputs[0]).suffix.lower() in SESSION_SUFFIXES
    scores = []
    if session:
        source = args.inputs[0]
        if args.rectified or args.truth:
            raise ReconError(
                "--rectified and --truth are for image pairs; a session stores its calibration"
            )
        check_outputs(
            [args.out or sidecar_path(source)],
            [source, args.calib],
            args.overwrite,
            directories=[args.ply_dir, args.maps_dir],
            writes="hdf5",
            sidecars=False,
        )
        bar = _LazyBar("frame", source)
        with bar:
            out = reconstruct_session(
                source, calibration=args.calib, progress=bar.update, started=bar.start, **common
            )
    else:
        pairs = image_pairs(args.inputs)
        check_outputs(
            [args.out or sidecar_path(pairs.lefts[0])],
            [*pairs.lefts, *pairs.rights, args.calib, args.truth],
            args.overwrite,
            directories=[args.ply_dir, args.maps_dir],
            writes="hdf5",
            sidecars=False,
        )
        calibration = pair_calibration(pairs.frame_size(), args.calib, _rectified(args))
        per_frame = None
        if args.truth:
            if pairs.n_frames != 1:
                raise ReconError(
                    f"--truth scores one pair; {args.inputs[0]} holds {pairs.n_frames}"
                )
            truth = truth_disparity(args.truth, calibration, args.truth_kind, args.truth_scale)

            def per_frame(_name, cloud):
                scores.append(score_disparity(cloud.disparity, truth, calibration))

        bar = _LazyBar("pair", args.inputs[0])
        with bar:
            out = reconstruct_images(
                pairs,
                calibration,
                progress=bar.update,
                per_frame=per_frame,
                started=bar.start,
                **common,
            )
    with CloudReader(out) as clouds:
        print(summary_line(clouds))
        warnings = quality_warnings(clouds, settings)
    for score in scores:
        print("\n".join(score.lines()))
    for warning in warnings:
        print(f"vbfe reconstruct: warning: {warning}", file=sys.stderr)
    if maps is not None:
        print(f"disparity, depth and quality maps ({maps.fmt}) in {maps.folder}")
    if args.ply_dir:
        files = export_ply(out, args.ply_dir)
        print(f"{len(files)} PLY files in {args.ply_dir}")
    return 0
