"""Evaluating a trained model's estimators on sessions, like the paper's Table I.

Errors are taken per frame as the length of the force error vector (the absolute error when
the model regresses one number): MAE, RMSE and σ (standard deviation of the absolute error),
overall and per condition (stiffness × pull speed), with 95 % intervals of the overall MAE and
RMSE from a block bootstrap over time (``bootstrap_intervals``: neighbouring frames are nearly
copies of each other, so frames are resampled in contiguous blocks, the same blocks for every
method). Every method's prediction of every scored frame is written to ``predictions.csv``
with its prediction interval (``intervals.py``: empirical coverage and mean width per method
and condition) and whether the frame is flagged (flagged frames counted per condition): it lies
outside the training data (``novelty.py``) or the shipped model parts ways with Hooke's law
(``disagreement.py``).
"""

from __future__ import annotations

import csv
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vbfe.common.errors import EstimateError
from vbfe.common.files import atomic_path
from vbfe.estimate.baselines import AffineBaseline
from vbfe.estimate.candidates import reads_texture
from vbfe.estimate.dataset import PreparedSession, ProgressFn, prepare_sessions, skipped_counts
from vbfe.estimate.disagreement import QUANTILE as DISAGREEMENT_QUANTILE
from vbfe.estimate.intervals import coverage_width
from vbfe.estimate.model_file import ForceModel, load_model
from vbfe.estimate.novelty import QUANTILE as NOVELTY_QUANTILE
from vbfe.estimate.preparation import target_label
from vbfe.estimate.report import plot_scatter, plot_session, safe_stem, write_json, write_tables
from vbfe.estimate.sources import SessionLike

BOOTSTRAP_BLOCKS = 20  # about this many time blocks over all scored frames
BOOTSTRAP_RESAMPLES = 1000


def error_stats(predicted_n: np.ndarray, measured_n: np.ndarray) -> dict[str, float]:
    """MAE, RMSE and σ of the per-frame absolute (vector) error, newtons."""
    error = np.linalg.norm(np.asarray(predicted_n) - np.asarray(measured_n), axis=1)
    return {
        "n_frames": int(len(error)),
        "mae_n": float(error.mean()),
        "rmse_n": float(np.sqrt((error**2).mean())),
        "sd_abs_error_n": float(error.std()),
    }


def time_blocks(lengths: Sequence[int], n_blocks: int = BOOTSTRAP_BLOCKS) -> list[np.ndarray]:
    """Contiguous blocks of frame positions (into the concatenated sessions of ``lengths``),
    never across sessions, of about ``total / n_blocks`` frames each."""
    size = max(1, int(round(sum(lengths) / n_blocks)))
    blocks, start = [], 0
    for n in lengths:
        blocks += [np.arange(start + a, start + min(a + size, n)) for a in range(0, n, size)]
        start += n
    return blocks


def bootstrap_intervals(
    errors: dict[str, np.ndarray], blocks: list[np.ndarray], seed: int = 0
) -> dict[str, dict[str, list[float]]]:
    """95 % percentile intervals of MAE and RMSE per method, resampling time ``blocks``."""
    rng = np.random.default_rng(seed)
    draws = [
        np.concatenate([blocks[i] for i in rng.integers(0, len(blocks), len(blocks))])
        for _ in range(BOOTSTRAP_RESAMPLES)
    ]
    out = {}
    for method, error in errors.items():
        mae = [error[d].mean() for d in draws]
        rmse = [np.sqrt((error[d] ** 2).mean()) for d in draws]
        out[method] = {
            "mae_ci95_n": np.percentile(mae, [2.5, 97.5]).tolist(),
            "rmse_ci95_n": np.percentile(rmse, [2.5, 97.5]).tolist(),
        }
    return out


@dataclass
class EvaluationReport:
    """Numbers and files of one evaluation."""

    out_dir: Path
    metrics: dict[str, dict[str, Any]]  # method → {"overall": stats + CIs, "per_condition": ...}
    sessions: list[str]
    seen_in_training: list[str]  # evaluated sessions the model was trained/validated on
    skipped: dict[str, dict[str, int]]
    selected: str = ""
    files: list[Path] = field(default_factory=list)
    split_description: str = ""  # how the model's training data was split
    # session → {"times_ns", "frame_index", "measured_n", method: predicted force}
    frames: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    # frames flagged outside the training data: {"overall": ..., "per_condition": ...}
    out_of_distribution: dict[str, Any] = field(default_factory=dict)

    def mae_n(self, method: str = "pointnet") -> float:
        """Overall MAE of one method (a candidate, a baseline, or ``selected``)."""
        return float(
            self.metrics[self.selected if method == "selected" else method]["overall"]["mae_n"]
        )


def _held_out_positions(model: ForceModel, session: PreparedSession) -> tuple[np.ndarray, bool]:
    """Frames of ``session`` to score and whether they were used in training.

    A session that the model's time split cut into ranges is scored on its test range only;
    if it has none, all its frames are scored and flagged as seen in training.
    """
    split = model.split
    everything = np.arange(session.n_used)
    if split.kind == "time" and any(
        split.contains(part, session.name) for part in ("train", "val", "test")
    ):
        test = split.positions("test", session)
        return (test, False) if len(test) else (everything, True)
    return everything, split.contains("train", session.name) or split.contains("val", session.name)


def write_predictions_csv(
    path: Path, frames: dict[str, dict[str, np.ndarray]], methods: Sequence[str], n_outputs: int
) -> Path:
    """One row per scored frame: session, frame, time, whether it is flagged (``ood`` 1/0:
    outside the training data, its ``novelty_m``, or off Hooke's law, ``disagreement_n``),
    measured and every method's force with, when the model has one, its interval
    (``<method>_lo_n``, ``<method>_hi_n``)."""
    columns = [f"_{k}" for k in range(n_outputs)] if n_outputs > 1 else [""]
    first = next(iter(frames.values()), {})
    keys = ["measured"]
    for name in methods:
        keys += [name] + [f"{name}_{b}" for b in ("lo", "hi") if f"{name}_{b}" in first]
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(
            [
                "session",
                "frame",
                "time_s",
                "ood",
                "novelty_m",
                "disagreement_n",
                *(f"{key}{c}_n" for key in keys for c in columns),
            ]
        )
        for session, data in frames.items():
            t0 = data["times_ns"][0] if len(data["times_ns"]) else 0
            for i in range(len(data["times_ns"])):
                values = [v for key in ("measured_n", *keys[1:]) for v in data[key][i]]
                writer.writerow(
                    [
                        session,
                        int(data["frame_index"][i]),
                        f"{(data['times_ns'][i] - t0) / 1e9:.6f}",
                        int(data["ood"][i]),
                        f"{data['novelty_m'][i]:.6g}",
                        f"{data['disagreement_n'][i]:.6g}",
                        *(f"{v:.6g}" for v in values),
                    ]
                )
    return path


def _with_intervals(
    model: ForceModel, per_method: dict[str, np.ndarray], protocol: str
) -> dict[str, np.ndarray]:
    """Every method's force and, for methods with an interval, ``<method>_lo``/``_hi`` (the
    interval of the session's ``protocol``)."""
    out = dict(per_method)
    for method, force in per_method.items():
        interval = model.interval(method)
        if interval is not None:
            out[f"{method}_lo"], out[f"{method}_hi"] = interval.bounds(force, protocol)
    return out


def _novelty(model: ForceModel, session: PreparedSession, positions: np.ndarray) -> np.ndarray:
    """Each scored frame's distance from the training data (NaN: the model has no flag)."""
    if model.novelty is None:
        return np.full(len(positions), np.nan)
    return model.novelty.distances(session, positions)


def _disagreement(model: ForceModel, per_method: dict[str, np.ndarray]) -> np.ndarray:
    """Each scored frame's difference between the shipped model and the check's reference
    (N; NaN: the model has no check)."""
    selected = per_method[model.selected]
    check = model.disagreement
    if check is None:
        return np.full(len(selected), np.nan)
    return check.distances(selected, per_method[check.reference])


def _stats(
    force: np.ndarray, truth: np.ndarray, bounds: list[np.ndarray] | None, mask: np.ndarray
) -> dict[str, Any]:
    """Error statistics of the ``mask``ed frames, with the interval's coverage and width."""
    stats: dict[str, Any] = error_stats(force[mask], truth[mask])
    if bounds is not None:
        stats.update(coverage_width(bounds[0][mask], bounds[1][mask], truth[mask]))
    return stats


def _flag_counts(flagged: np.ndarray, labels: np.ndarray) -> dict[str, Any]:
    """Frames flagged outside the training data, overall and per condition."""

    def count(mask: np.ndarray) -> dict[str, Any]:
        n = int(mask.sum())
        return {
            "n_frames": n,
            "flagged": int(flagged[mask].sum()),
            "share": float(flagged[mask].mean()) if n else 0.0,
        }

    return {
        "overall": count(np.ones(len(flagged), bool)),
        "per_condition": {c: count(labels == c) for c in sorted(set(labels.tolist()))},
    }


def evaluate(
    model_path: str | Path,
    sessions: Sequence[SessionLike] | None,
    out_dir: str | Path,
    progress: ProgressFn | None = None,
) -> EvaluationReport:
    """Evaluate every estimator of a model file; writes metrics.json, predictions.csv,
    report.md/.html and PNGs.

    With ``sessions=None`` the sessions in the model's recorded test split are used. Sessions
    of a time split are scored on their held-out test range only. Torch's thread count is
    left as the caller set it.
    """
    model = load_model(model_path)
    if not sessions:
        sessions = model.split.test
        if not sessions:
            raise EstimateError(
                f"{model_path} has no recorded test sessions: give the sessions to evaluate"
            )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    prepared = prepare_sessions(
        sessions, model.config, progress, texture=any(map(reads_texture, model.estimators.values()))
    )
    protocols = sorted({s.protocol for s in prepared})
    shipped = "one model for every protocol"
    if model.by_protocol:
        if len(protocols) == 1:  # the sessions say their protocol: the method shipped for it
            model = model.for_protocol(protocols[0])
            shipped = f"the method shipped for {protocols[0]} sessions"
        else:
            shipped += f" (sessions of {', '.join(protocols)}: evaluate each protocol apart)"
    methods = [model.selected, *(m for m in model.estimators if m != model.selected)]
    label = target_label(model.config.target)

    predictions: dict[str, list[np.ndarray]] = defaultdict(list)
    measured, labels, plots, seen_in_training = [], [], [], []
    frames: dict[str, dict[str, np.ndarray]] = {}
    for k, session in enumerate(prepared):
        positions, seen = _held_out_positions(model, session)
        if seen:
            seen_in_training.append(session.name)
        per_method = _with_intervals(
            model,
            {m: model.predict_session(session, m, positions) for m in methods},
            session.protocol,
        )
        for method, force in per_method.items():
            predictions[method].append(force)
        measured.append(session.targets_n[positions])
        novelty = _novelty(model, session, positions)
        flagged = model.flagged(novelty, per_method)
        frames[session.name] = {
            "times_ns": session.times_ns[positions],
            "frame_index": session.frame_index[positions],
            "measured_n": session.targets_n[positions],
            "novelty_m": novelty,
            "disagreement_n": _disagreement(model, per_method),
            "ood": flagged,
            **per_method,
        }
        labels += [session.condition] * len(positions)
        plots.append(
            plot_session(
                out_dir / f"force_{k:02d}_{safe_stem(session.name)}.png",
                f"{session.name} ({session.condition})",
                session.times_ns[positions],
                session.targets_n[positions],
                per_method,
                label,
                model.selected,
                flagged,
            )
        )
        if progress is not None:
            progress("predict", k + 1, len(prepared))

    truth = np.concatenate(measured)
    label_array = np.asarray(labels)
    errors = {m: np.linalg.norm(np.concatenate(predictions[m]) - truth, axis=1) for m in methods}
    intervals = bootstrap_intervals(errors, time_blocks([len(m) for m in measured]))
    metrics: dict[str, dict[str, Any]] = {}
    for method in methods:
        force = np.concatenate(predictions[method])
        bounds = (
            [np.concatenate(predictions[f"{method}_{b}"]) for b in ("lo", "hi")]
            if f"{method}_lo" in predictions
            else None
        )
        everything = np.ones(len(truth), bool)
        metrics[method] = {
            "overall": {**_stats(force, truth, bounds, everything), **intervals[method]},
            "per_condition": {
                c: _stats(force, truth, bounds, label_array == c) for c in sorted(set(labels))
            },
        }
    flags = _flag_counts(np.concatenate([f["ood"] for f in frames.values()]), label_array)
    plots.append(
        plot_scatter(
            out_dir / "scatter_selected.png",
            truth,
            np.concatenate(predictions[model.selected]),
            labels,
            label,
            model.selected,
        )
    )

    names = [s.name for s in prepared]
    skipped = skipped_counts(prepared)
    split = model.split
    split_note = f"training {split.describe()}" + (
        "; scored on the held-out test ranges only" if split.kind == "time" else ""
    )
    notes = [
        f"model {Path(model_path).name} (vbfe {model.record.get('vbfe_version')}), "
        f"target {model.config.target} ({label})",
        f"selected model: {model.selected} ({shipped}); validation MAE per method (N): "
        + ", ".join(f"{m} {v:.3f}" for m, v in model.record.get("validation_mae_n", {}).items()),
        *(
            n
            for n in model.record.get("notes", [])
            if n.startswith(("warning", "selected model", "held-out MAE"))
        ),
        split_note,
        "MAE/RMSE 95 % intervals: bootstrap over contiguous time blocks "
        f"({BOOTSTRAP_RESAMPLES} resamples of {len(time_blocks([len(m) for m in measured]))}"
        " blocks)",
        f"frames not scored: {sum(v['no_force'] for v in skipped.values())} without a "
        f"force, {sum(v['no_cloud'] for v in skipped.values())} with too few points in "
        "the region of interest",
    ]
    hooke = model.estimators.get("hooke")
    if isinstance(hooke, AffineBaseline):
        notes.append(
            "baselines fitted on the training frames only; Hooke uses one fitted "
            f"stiffness k̂ = {hooke.slope.round(2).tolist()} N/m"
        )
    if model.novelty is not None:
        overall = flags["overall"]
        check = model.disagreement
        notes.append(
            f"flagged (outside the training data{', or off Hooke' if check else ''}): "
            f"{overall['flagged']} of {overall['n_frames']} frames "
            f"({100 * overall['share']:.1f} %; "
            + ", ".join(
                f"{c} {v['flagged']}/{v['n_frames']}" for c, v in flags["per_condition"].items()
            )
            + f"); a frame is flagged when its distance from the training frames exceeds "
            f"{model.novelty.threshold * 1e3:.3f} mm (the {NOVELTY_QUANTILE:g} quantile of "
            "the training frames' own)"
            + (
                f" or when {model.selected} and {check.reference} differ by more than half "
                f"{model.selected}'s interval width at the frame and {check.threshold_n:.3f} N "
                f"(the {DISAGREEMENT_QUANTILE:g} quantile of their difference on held-out frames)"
                if check
                else ""
            )
        )
    else:
        notes.append("no flag of frames outside the training data (model file without one)")
    interval = model.interval()
    notes.append(
        f"prediction intervals: {100 * interval.coverage:g} % nominal, calibrated on "
        f"{interval.n_calibration} held-out frames ({interval.source}), width "
        + ("constant" if interval.scale == "none" else "growing with |F|")
        + (
            "; per protocol, from its own frames: "
            + ", ".join(f"{k or 'unstated'} ±{v[0]:.3g}" for k, v in interval.protocols.items())
            if interval.protocols
            else ""
        )
        if interval is not None
        else "no prediction intervals (model file without them)"
    )
    if seen_in_training:
        notes.append(
            f"WARNING: {len(seen_in_training)} evaluated session(s) were used in "
            "training; these numbers are not held-out"
        )
    csv_path = write_predictions_csv(
        out_dir / "predictions.csv", frames, methods, model.config.n_outputs
    )
    metrics_path = write_json(
        out_dir / "metrics.json",
        {
            "model": str(model_path),
            "selected": model.selected,
            "target": model.config.target,
            "sessions": names,
            "seen_in_training": seen_in_training,
            "split": {
                "kind": split.kind,
                "gap_frames": split.gap_frames,
                "description": split.describe(),
                "blocks": split.blocks,
            },
            "skipped": skipped,
            "units": "N",
            "metrics": metrics,
            "out_of_distribution": flags,
        },
    )
    md_path, html_path = write_tables(out_dir, metrics, notes, plots)
    return EvaluationReport(
        out_dir=out_dir,
        metrics=metrics,
        sessions=names,
        seen_in_training=seen_in_training,
        skipped=skipped,
        selected=model.selected,
        files=[metrics_path, csv_path, md_path, html_path, *plots],
        split_description=split_note,
        frames=frames,
        out_of_distribution=flags,
    )
