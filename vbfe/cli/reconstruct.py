"""`vbfe reconstruct`: point clouds of every frame of a recorded session."""

from __future__ import annotations

import argparse

from vbfe.cli.common import add_config_option, check_output_path, config_from, progress
from vbfe.config import section


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `reconstruct` subcommand."""
    parser = sub.add_parser(
        "reconstruct", help="structured-light stereo point clouds of a session",
        description="Rectify, match (SGBM + De Bruijn verification) and triangulate every frame "
        "of SESSION.h5 into SESSION.clouds.h5 next to it.")
    parser.add_argument("session", metavar="SESSION.h5", help="recorded session")
    parser.add_argument("--calib", metavar="FILE", default=None,
                        help="calibration YAML (default: the one stored in the session)")
    parser.add_argument("--out", metavar="CLOUDS.h5", default=None,
                        help="output file (default: SESSION.clouds.h5)")
    parser.add_argument("--workers", type=int, default=None,
                        help="parallel processes (default: one per CPU core)")
    parser.add_argument("--no-verify", action="store_true",
                        help="skip the De Bruijn verification (bare SGBM)")
    parser.add_argument("--ply-dir", metavar="DIR", default=None,
                        help="also write one PLY file per frame into DIR")
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Reconstruct the session and report where the clouds went."""
    from vbfe.acquire import SessionReader
    from vbfe.recon.clouds import CloudReader, export_ply
    from vbfe.recon.matching import SgbmParams
    from vbfe.recon.session_recon import reconstruct_session, resolve_calibration

    params = SgbmParams.from_config(section(config_from(args), "sgbm"))
    if args.out:
        check_output_path(args.out, "clouds file")
    if args.ply_dir:
        check_output_path(args.ply_dir, "PLY folder", folder=True)
    calibration = resolve_calibration(args.session, args.calib)
    with SessionReader(args.session) as reader:
        n_frames = reader.n_frames
    with progress(total=n_frames, desc="reconstruct", unit="frame") as bar:
        out = reconstruct_session(args.session, calibration=calibration, out_path=args.out,
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
