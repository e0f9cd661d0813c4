"""`vbfe reconstruct`: point clouds of every frame of recorded sessions."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from vbfe.cli.batch_options import add_batch_options, batch_settings, run_batch
from vbfe.cli.common import add_config_option, config_from, progress
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.config import section


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `reconstruct` subcommand."""
    parser = sub.add_parser(
        "reconstruct", help="structured-light stereo point clouds of sessions",
        description="Rectify, match (SGBM + De Bruijn verification) and triangulate every frame "
        "of SESSION.h5 into SESSION.clouds.h5 next to it. Several sessions or a manifest CSV "
        "(vbfe dataset) run one task per session on a local process pool or a Ray cluster; "
        "sessions whose clouds are current are skipped.")
    parser.add_argument("sessions", nargs="+", metavar="SESSION.h5|MANIFEST.csv",
                        help="recorded session(s), or a manifest")
    parser.add_argument("--calib", metavar="FILE", default=None,
                        help="calibration YAML (default: the one stored in each session)")
    parser.add_argument("--out", metavar="CLOUDS.h5", default=None,
                        help="output file of a single session (default: SESSION.clouds.h5)")
    parser.add_argument("--workers", type=int, default=None,
                        help="parallel processes: frames of one session, or sessions of many "
                        "(default: one per CPU core)")
    parser.add_argument("--no-verify", action="store_true",
                        help="skip the De Bruijn verification (bare SGBM)")
    parser.add_argument("--ply-dir", metavar="DIR", default=None,
                        help="also write one PLY file per frame into DIR (single session)")
    add_batch_options(parser)
    add_overwrite_option(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Reconstruct the session(s) and report where the clouds went."""
    from vbfe.batch.errors import BatchError
    from vbfe.batch.manifest import expand_sessions
    from vbfe.recon.matching import SgbmParams

    config = config_from(args)
    params = SgbmParams.from_config(section(config, "sgbm"))
    sessions = expand_sessions(args.sessions)
    if len(sessions) == 1 and not args.sessions[0].endswith(".csv") and not args.executor:
        return _run_one(args, str(sessions[0]), params)
    if args.out or args.ply_dir:
        raise BatchError("--out and --ply-dir take a single session; with several, each "
                         "session's clouds go next to it")
    from vbfe.batch.tasks import ReconstructTask

    executor, address = batch_settings(args, config.get("batch", {}))
    task = ReconstructTask(sgbm=dataclasses.asdict(params), verify=not args.no_verify,
                           calibration=args.calib, overwrite=args.overwrite)
    run_batch(task, sessions, executor, args.workers, address, "reconstruct",
              lambda v: v["action"] + (f", {v['frames']} frames, mean valid pixels "
                                       f"{v['valid_fraction']:.1%}" if "frames" in v else ""))
    return 0


def _run_one(args: argparse.Namespace, session: str, params: object) -> int:
    from vbfe.acquire import SessionReader
    from vbfe.recon.clouds import CloudReader, export_ply
    from vbfe.recon.clouds import sidecar_path
    from vbfe.recon.session_recon import reconstruct_session, resolve_calibration

    check_outputs([args.out or sidecar_path(session)], [session, args.calib],
                  args.overwrite, directories=[args.ply_dir])
    calibration = resolve_calibration(session, args.calib)
    with SessionReader(session) as reader:
        n_frames = reader.n_frames
        if reader.growing:
            print(f"vbfe reconstruct: {session} is still being recorded: reconstructing its "
                  f"{n_frames} frames flushed so far (the output is marked partial)",
                  file=sys.stderr)
    with progress(total=n_frames, desc="reconstruct", unit="frame") as bar:
        out = reconstruct_session(session, calibration=calibration, out_path=args.out,
                                  workers=args.workers, progress=bar.update, sgbm_params=params,
                                  verify=not args.no_verify)
    with CloudReader(out) as clouds:
        valid = clouds.frame_table("valid_fraction")
    print(f"{out}: {len(valid)} frames, mean valid pixels {valid.mean():.1%}"
          if len(valid) else f"{out}: no frames")
    if args.ply_dir:
        files = export_ply(out, args.ply_dir)
        print(f"{len(files)} PLY files in {args.ply_dir}")
    return 0
