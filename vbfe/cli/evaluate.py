"""`vbfe evaluate`: errors of a trained model and its baselines, with plots and a report."""

from __future__ import annotations

import argparse

from vbfe.cli.common import StageProgress, check_output_path


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `evaluate` subcommand."""
    parser = sub.add_parser("evaluate", help="evaluate a trained model and the baselines",
                            description="MAE, RMSE and σ of the model and baselines, overall "
                            "and per condition; writes metrics.json, report.md/.html and plots. "
                            "Without sessions, the model's recorded test split is used.")
    parser.add_argument("model", metavar="MODEL.pt")
    parser.add_argument("sessions", nargs="*", metavar="SESSION.h5")
    parser.add_argument("--out", required=True, metavar="DIR", help="report directory")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Evaluate and print the overall MAE of every method."""
    from vbfe.estimate import evaluate  # torch loads only when a command needs it

    check_output_path(args.out, "report folder", folder=True)
    bars = StageProgress()
    try:
        report = evaluate(args.model, args.sessions or None, args.out, progress=bars)
    finally:
        bars.close()
    for method, numbers in report.metrics.items():
        overall = numbers["overall"]
        print(f"{method:>20}: MAE {overall['mae_n']:.3f} N (σ {overall['sd_abs_error_n']:.3f}), "
              f"RMSE {overall['rmse_n']:.3f} N over {overall['n_frames']} frames")
    if report.seen_in_training:
        print(f"warning: {len(report.seen_in_training)} session(s) were used in training")
    print(f"report: {report.out_dir / 'report.md'}")
    return 0
