"""`vbfe train`: fit every force estimator, ship the best on validation, optionally
cross-validate."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vbfe.cli.common import (
    StageProgress,
    add_config_option,
    add_settle_option,
    check_settle,
    positive,
    rig_from,
    settle_values,
)
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.common.files import require_free_space

MODEL_FREE_BYTES = 64 << 20  # a model file with its baselines and training record, with room


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `train` subcommand."""
    parser = sub.add_parser(
        "train",
        help="train the force estimators on reconstructed sessions",
        description="Fit every candidate (PointNet, the temporal model, "
        "ridge on depth-change thumbnails, a small CNN on the depth-change "
        "image, the mean of that CNN and Hooke's law) and the baselines on the "
        "training part, and ship the candidate with the lowest validation MAE (on "
        "blocked folds of the training part when validation is small; a baseline "
        "when it beats every candidate), or the one --model forces. Every method "
        "gets a prediction interval calibrated on the same held-out residuals. "
        "Each session needs its <session>.clouds.h5 sidecar (run "
        "`vbfe reconstruct` first) or is a clouds file from `vbfe import`. "
        "Defaults come from the [train] table of the rig config.",
    )
    parser.add_argument(
        "sessions",
        nargs="+",
        metavar="SESSION.h5|MANIFEST.csv",
        help="sessions, or a manifest CSV written by vbfe dataset",
    )
    parser.add_argument("--out", required=True, metavar="MODEL.pt", help="model file to write")
    add_settle_option(parser, "the model as the one vbfe live loads ([live] model)")
    parser.add_argument("--epochs", type=int, help="maximum epochs (early stopping may end sooner)")
    parser.add_argument("--points", type=int, dest="n_points", help="points per cloud")
    parser.add_argument("--batch-size", type=int, help="clouds per step ([train] batch_size)")
    parser.add_argument(
        "--learning-rate", type=float, help="NAdam's initial rate ([train] learning_rate)"
    )
    parser.add_argument(
        "--target",
        metavar="magnitude|xyz|AXIS",
        help="regress |F|, the 3 axes, or one signed axis (x, -z, ...)",
    )
    parser.add_argument(
        "--model",
        metavar="auto|pointnet|temporal|ridge|cnn|ensemble|hooke_texture",
        help="auto (default): the candidate best on validation; else force one",
    )
    parser.add_argument(
        "--split",
        metavar="session|time",
        help="hold out whole sessions (default) or "
        "the end of each session in time (train, then validation, then test)",
    )
    for part, example in (("train", "0:565"), ("val", "595:700"), ("test", "730:1000")):
        parser.add_argument(
            f"--{part}",
            dest=f"{part}_frames",
            metavar="START:STOP",
            help=f"time split: the {part} frames of every session, e.g. {example}",
        )
    parser.add_argument(
        "--folds",
        type=int,
        metavar="K",
        help="blocked cross-validation in time "
        "with K folds first (mean ± sd per method), then the shipped model",
    )
    parser.add_argument(
        "--gap",
        type=int,
        dest="gap_frames",
        metavar="FRAMES",
        help="time split: frames left out at every boundary between parts",
    )
    parser.add_argument("--val-fraction", type=float, help="share held out for validation")
    parser.add_argument("--test-fraction", type=float, help="share held out for test")
    parser.add_argument(
        "--temporal-frames",
        type=int,
        metavar="K",
        help="also train the temporal model on a causal window of K frames",
    )
    parser.add_argument(
        "--device",
        metavar="auto|cpu|cuda",
        help="where the networks train: auto (default: cuda when torch sees a GPU, else cpu; "
        "the last line says which), cpu or cuda",
    )
    parser.add_argument(
        "--time-limit",
        type=positive(float),
        dest="time_limit_s",
        metavar="SECONDS",
        help="stop a network's training after this long, with a warning ([train] time_limit_s)",
    )
    parser.add_argument(
        "--seed", type=int, help="of the split, the sampling and the weights ([train] seed)"
    )
    parser.add_argument(
        "--coverage",
        type=float,
        dest="interval_coverage",
        metavar="FRACTION",
        help="coverage of the prediction intervals (default 0.9)",
    )
    add_overwrite_option(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Train; print the split as frame ranges, every method's validation MAE and what ships."""
    from vbfe.batch.manifest import expand_sessions
    from vbfe.estimate import TrainConfig
    from vbfe.estimate.splits import parse_range

    overrides = {
        key: getattr(args, key)
        for key in (
            "epochs",
            "n_points",
            "batch_size",
            "learning_rate",
            "target",
            "split",
            "gap_frames",
            "val_fraction",
            "test_fraction",
            "temporal_frames",
            "device",
            "time_limit_s",
            "seed",
            "model",
            "folds",
            "interval_coverage",
        )
    }
    for part in ("train", "val", "test"):
        text = getattr(args, f"{part}_frames")
        overrides[f"{part}_frames"] = parse_range(text, f"--{part}") if text else None
    if overrides["train_frames"]:
        overrides["split"] = "time"
    config = TrainConfig.from_table(rig_from(args).tables["train"], **overrides)
    check_outputs([args.out], args.sessions, args.overwrite)
    check_settle(args)
    require_free_space(Path(args.out).absolute().parent, MODEL_FREE_BYTES, f"the model {args.out}")
    from vbfe.estimate import train  # torch loads once the inputs are checked

    bars = StageProgress()
    try:
        result = train(
            [str(p) for p in expand_sessions(args.sessions)], args.out, config, progress=bars
        )
    finally:
        bars.close()
    for note in result.notes:
        print(note, file=sys.stderr if note.startswith("warning:") else sys.stdout)
    print(
        "validation MAE (N): "
        + ", ".join(f"{name} {mae:.3f}" for name, mae in result.val_mae_n.items())
    )
    interval = result.intervals.get(result.selected)
    if interval:
        print(
            f"{100 * interval['coverage']:g} % prediction interval of {result.selected}: ± "
            + ", ".join(f"{q:.3f}" for q in interval["quantile"])
            + (" N" if interval["scale"] == "none" else f" × ({interval['floor_n']:.3f} N + |F|)")
            + f", calibrated on {interval['n_calibration']} held-out frames ({interval['source']})"
        )
    if result.cross_validation:
        print_cross_validation(result.cross_validation)
    print(
        f"model written to {result.model_path}: ships {result.selected}"
        + "".join(f", for {p} frames {n}" for p, n in result.by_protocol.items())
        + " "
        f"({result.duration_s:.0f} s, networks on {result.device}, torch on "
        f"{config.threads} CPU thread(s))"
    )
    skipped = {
        key: sum(v[key] for v in result.skipped.values()) for key in ("no_force", "no_cloud")
    }
    if any(skipped.values()):
        print(
            f"frames not used: {skipped['no_force']} without a force, {skipped['no_cloud']} "
            "with too few points in the region of interest"
        )
    settle_values(args, {"live": {"model": str(Path(result.model_path).resolve())}})
    return 0


def print_cross_validation(cv: dict) -> None:
    """Every fold's frame ranges and test MAEs, then mean ± sd per method."""
    for k, fold in enumerate(cv["folds"]):
        print(
            f"fold {k + 1}: {fold['description']}; selected {fold['selected']}; test MAE (N): "
            + ", ".join(f"{m} {v:.3f}" for m, v in fold["test_mae_n"].items())
        )
    k = len(cv["folds"])
    short = [  # trained on under half the (K − 2) blocks a fold would train on without gaps
        (n + 1, fold["n_train_frames"])
        for n, fold in enumerate(cv["folds"])
        if fold["n_train_frames"] < (k - 2) * fold["n_test_frames"] / 2
    ]
    if short:
        print(
            f"warning: the gap of {cv['gap_frames']} frames leaves "
            + ", ".join(f"fold {n} {m} training frames" for n, m in short)
            + f" (about {cv['folds'][0]['n_test_frames']} frames per block): a short "
            "recording; lower --gap for folds that can fit"
        )
    print(f"{k}-fold blocked cross-validation, test MAE mean ± sd (N):")
    for method, s in sorted(cv["summary"].items(), key=lambda kv: kv[1]["mean_mae_n"]):
        print(
            f"  {method:>24}: {s['mean_mae_n']:.3f} ± {s['sd_mae_n']:.3f}"
            + (
                f"; interval coverage {100 * s['interval_coverage']:.1f} %, mean width "
                f"{s['interval_width_n']:.3f}"
                if "interval_coverage" in s
                else ""
            )
        )
