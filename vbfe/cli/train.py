"""`vbfe train`: fit the PointNet force regressor on reconstructed sessions."""

from __future__ import annotations

import argparse
import sys

from vbfe.cli.common import StageProgress, add_config_option, check_output_path, config_from
from vbfe.config import section

def register(sub: argparse._SubParsersAction) -> None:
    """Add the `train` subcommand."""
    parser = sub.add_parser("train", help="train the force regressor on reconstructed sessions",
                            description="Train the PointNet force regressor. Each session needs "
                            "its <session>.clouds.h5 sidecar (run `vbfe reconstruct` first). "
                            "Defaults come from the [train] table of the rig config.")
    parser.add_argument("sessions", nargs="+", metavar="SESSION.h5")
    parser.add_argument("--out", required=True, metavar="MODEL.pt", help="model file to write")
    parser.add_argument("--epochs", type=int, help="maximum epochs (early stopping may end sooner)")
    parser.add_argument("--points", type=int, dest="n_points", help="points per cloud")
    parser.add_argument("--batch-size", type=int)
    parser.add_argument("--learning-rate", type=float)
    parser.add_argument("--target", choices=("magnitude", "xyz"), help="regress |F| or 3 axes")
    parser.add_argument("--val-fraction", type=float, help="share of sessions for validation")
    parser.add_argument("--test-fraction", type=float, help="share of sessions held out for test")
    parser.add_argument("--time-limit", type=float, dest="time_limit_s", metavar="SECONDS")
    parser.add_argument("--seed", type=int)
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Train and print where the model went and how it compares with the mean predictor."""
    from vbfe.estimate import TrainConfig, train  # torch loads only when a command needs it

    overrides = {key: getattr(args, key) for key in
                 ("epochs", "n_points", "batch_size", "learning_rate", "target", "val_fraction",
                  "test_fraction", "time_limit_s", "seed")}
    config = TrainConfig.from_table(section(config_from(args), "train"), **overrides)
    check_output_path(args.out, "model file")
    bars = StageProgress()
    try:
        result = train(args.sessions, args.out, config, progress=bars)
    finally:
        bars.close()
    print(f"model written to {result.model_path} (best epoch {result.best_epoch} of "
          f"{result.epochs_run}, {result.duration_s:.0f} s)")
    if not result.split.val:
        print("warning: no session was held out for validation (one session, or too few for "
              "--val-fraction): the MAE below is the training MAE; train on several sessions "
              "for an honest validation error", file=sys.stderr)
    print(f"{'validation' if result.split.val else 'training'} MAE {result.val_mae_n:.3f} N; "
          "baselines: " + ", ".join(
        f"{name} {mae:.3f} N" for name, mae in result.baseline_val_mae_n.items()))
    skipped = sum(v["skipped"] for v in result.skipped.values())
    if skipped:
        print(f"skipped {skipped} empty/NaN frames")
    return 0
