"""`vbfe train`: fit the PointNet force regressor on reconstructed sessions."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vbfe.cli.common import StageProgress, add_config_option, config_from, positive
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.config import section
from vbfe.files import require_free_space

MODEL_FREE_BYTES = 64 << 20  # a model file with its baselines and training record, with room

def register(sub: argparse._SubParsersAction) -> None:
    """Add the `train` subcommand."""
    parser = sub.add_parser("train", help="train the force regressor on reconstructed sessions",
                            description="Train the PointNet force regressor. Each session needs "
                            "its <session>.clouds.h5 sidecar (run `vbfe reconstruct` first). "
                            "Defaults come from the [train] table of the rig config.")
    parser.add_argument("sessions", nargs="+", metavar="SESSION.h5|MANIFEST.csv",
                        help="sessions, or a manifest CSV written by vbfe dataset")
    parser.add_argument("--out", required=True, metavar="MODEL.pt", help="model file to write")
    parser.add_argument("--epochs", type=int, help="maximum epochs (early stopping may end sooner)")
    parser.add_argument("--points", type=int, dest="n_points", help="points per cloud")
    parser.add_argument("--batch-size", type=int)
    parser.add_argument("--learning-rate", type=float)
    parser.add_argument("--target", metavar="magnitude|xyz|AXIS",
                        help="regress |F|, the 3 axes, or one signed axis (x, -z, ...)")
    parser.add_argument("--split", metavar="session|time", help="hold out whole sessions (default) or "
                        "contiguous time blocks inside each session")
    parser.add_argument("--gap", type=int, dest="gap_frames", metavar="FRAMES",
                        help="time split: frames left out at every boundary between parts")
    parser.add_argument("--val-fraction", type=float, help="share held out for validation")
    parser.add_argument("--test-fraction", type=float, help="share held out for test")
    parser.add_argument("--temporal-frames", type=int, metavar="K",
                        help="also train the temporal model on a causal window of K frames")
    parser.add_argument("--device", metavar="auto|cpu|cuda", help="cpu (default), cuda, or auto")
    parser.add_argument("--time-limit", type=positive(float), dest="time_limit_s",
                        metavar="SECONDS")
    parser.add_argument("--seed", type=int)
    add_overwrite_option(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Train and print where the model went and how it compares with the mean predictor."""
    from vbfe.batch.manifest import expand_sessions
    from vbfe.estimate import TrainConfig, train, use_threads  # torch loads only when needed

    check_outputs([args.out], args.sessions, args.overwrite)
    require_free_space(Path(args.out).absolute().parent, MODEL_FREE_BYTES, f"the model {args.out}")
    overrides = {key: getattr(args, key) for key in
                 ("epochs", "n_points", "batch_size", "learning_rate", "target", "split",
                  "gap_frames", "val_fraction", "test_fraction", "temporal_frames", "device",
                  "time_limit_s", "seed")}
    config = TrainConfig.from_table(section(config_from(args), "train"), **overrides)
    use_threads(config.threads)
    bars = StageProgress()
    try:
        result = train([str(p) for p in expand_sessions(args.sessions)], args.out, config,
                       progress=bars)
    finally:
        bars.close()
    print(f"model written to {result.model_path} (best epoch {result.best_epoch} of "
          f"{result.epochs_run}, {result.duration_s:.0f} s)")
    for note in result.notes:
        print(note, file=sys.stderr if note.startswith("warning:") else sys.stdout)
    temporal = ("" if result.temporal_val_mae_n is None
                else f", temporal model {result.temporal_val_mae_n:.3f} N")
    print(f"validation MAE: PointNet {result.val_mae_n:.3f} N{temporal}; baselines: " + ", ".join(
        f"{name} {mae:.3f} N" for name, mae in result.baseline_val_mae_n.items()))
    skipped = sum(v["skipped"] for v in result.skipped.values())
    if skipped:
        print(f"skipped {skipped} empty/NaN frames")
    return 0
