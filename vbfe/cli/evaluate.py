"""`vbfe evaluate`: errors of a trained model and its baselines, with plots and a report; or
the score of a live estimate stream recorded by `vbfe live --record`."""

from __future__ import annotations

import argparse

from vbfe.cli.common import StageProgress, add_config_option, rig_from
from vbfe.cli.outputs import add_overwrite_option, check_outputs


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `evaluate` subcommand."""
    parser = sub.add_parser(
        "evaluate",
        help="evaluate a trained model and the baselines",
        description="MAE, RMSE (with 95 % block-bootstrap intervals) and σ "
        "of the selected model, every other candidate and the baselines, "
        "overall and per condition; writes metrics.json, predictions.csv "
        "(per frame), report.md/.html and plots. "
        "Without sessions, the model's recorded test split is used. With "
        "--live SESSION.h5, scores the estimates that `vbfe live --record` "
        "stored in the session against its trocar.",
    )
    parser.add_argument("model", metavar="MODEL.pt", nargs="?", help="from vbfe train")
    parser.add_argument(
        "sessions",
        nargs="*",
        metavar="SESSION.h5|MANIFEST.csv",
        help="sessions, or a manifest CSV written by vbfe dataset",
    )
    parser.add_argument(
        "--live",
        metavar="SESSION.h5",
        default=None,
        help="score the live estimate stream of this session",
    )
    parser.add_argument("--out", metavar="DIR", default=None, help="report directory")
    add_overwrite_option(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def _run_live(args: argparse.Namespace) -> int:
    from vbfe.estimate.live_score import score_live_stream

    check_outputs([], [args.live], args.overwrite, directories=[args.out])
    score = score_live_stream(args.live, args.out)
    e = score["error"]
    print(
        f"live estimates of {args.live}: MAE {e['mae_n']:.3f} N (σ {e['sd_abs_error_n']:.3f}), "
        f"RMSE {e['rmse_n']:.3f} N over {score['compared']} of {score['estimates']} estimates "
        f"(target {score['target']}, synchronised times)"
    )
    print(
        f"rate {score['rate_hz']:.1f} estimates/s, latency p50 {score['latency_ms']['p50']:.1f}"
        f" ms, p95 {score['latency_ms']['p95']:.1f} ms, {score['skipped_frames']} frames "
        f"skipped; per stage (median): "
        + ", ".join(f"{k} {v:.1f} ms" for k, v in score["stage_median_ms"].items())
    )
    for path in score.get("files", []):
        print(f"wrote {path}")
    return 0


def run(args: argparse.Namespace) -> int:
    """Evaluate and print the overall MAE of every method."""
    from vbfe.common.errors import EstimateError

    if args.live:
        if args.model or args.sessions:
            raise EstimateError(
                "--live scores a recorded estimate stream: give only "
                "--live SESSION.h5 [--out DIR], no model or sessions"
            )
        return _run_live(args)
    if not args.model or not args.out:
        raise EstimateError("give MODEL.pt and --out DIR (or --live SESSION.h5)")
    from vbfe.batch.manifest import expand_sessions
    from vbfe.estimate import evaluate, use_threads  # torch loads only when needed

    check_outputs([], [args.model, *args.sessions], args.overwrite, directories=[args.out])
    use_threads(rig_from(args).train.threads)
    bars = StageProgress()
    try:
        sessions = [str(p) for p in expand_sessions(args.sessions)]
        report = evaluate(args.model, sessions or None, args.out, progress=bars)
    finally:
        bars.close()
    for method, numbers in report.metrics.items():
        o = numbers["overall"]
        shipped = " (selected)" if method == report.selected else ""
        print(
            f"{method + shipped:>35}: MAE {o['mae_n']:.3f} N [95 % {o['mae_ci95_n'][0]:.3f}, "
            f"{o['mae_ci95_n'][1]:.3f}], RMSE {o['rmse_n']:.3f} N [{o['rmse_ci95_n'][0]:.3f}, "
            f"{o['rmse_ci95_n'][1]:.3f}] over {o['n_frames']} frames"
            + (
                f"; interval coverage {100 * o['interval_coverage']:.1f} %, mean width "
                f"{o['interval_width_n']:.3f} N"
                if "interval_coverage" in o
                else ""
            )
        )
    flags = report.out_of_distribution["overall"]
    print(
        f"flagged (outside the training data, or off Hooke's law): {flags['flagged']} of "
        f"{flags['n_frames']} frames"
    )
    print(report.split_description)
    if report.seen_in_training:
        print(f"warning: {len(report.seen_in_training)} session(s) were used in training")
    skipped = {
        key: sum(v[key] for v in report.skipped.values()) for key in ("no_force", "no_cloud")
    }
    print(
        f"frames not scored: {skipped['no_force']} without a force, {skipped['no_cloud']} with "
        "too few points in the region of interest"
    )
    print(f"per-frame predictions: {report.out_dir / 'predictions.csv'}")
    print(f"report: {report.out_dir / 'report.md'}")
    return 0
