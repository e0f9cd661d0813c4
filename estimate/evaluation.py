"""Evaluating a trained model and its baselines on sessions, like the paper's Table I.

Errors are taken per frame as the length of the force error vector (the absolute error when
the model regresses |F|): MAE, RMSE and σ (standard deviation of the absolute error), overall and
per condition (stiffness × pull speed).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from vbfe.estimate.dataset import PreparedSession, ProgressFn, prepare_sessions, skipped_counts
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.model_file import ForceModel, load_model
from vbfe.estimate.report import plot_scatter, plot_session, safe_stem, write_json, write_tables
from vbfe.estimate.sources import SessionLike


def error_stats(predicted_n: np.ndarray, measured_n: np.ndarray) -> dict[str, float]:
    """MAE, RMSE and σ of the per-frame absolute (vector) error, newtons."""
    error = np.linalg.norm(np.asarray(predicted_n) - np.asarray(measured_n), axis=1)
    return {"n_frames": int(len(error)), "mae_n": float(error.mean()),
            "rmse_n": float(np.sqrt((error ** 2).mean())),
            "sd_abs_error_n": float(error.std())}


@dataclass
class EvaluationReport:
    """Numbers and files of one evaluation."""

    out_dir: Path
    metrics: dict[str, dict[str, Any]]  # method → {"overall": stats, "per_condition": {...}}
    sessions: list[str]
    seen_in_training: list[str]  # evaluated sessions the model was trained/validated on
    skipped: dict[str, dict[str, int]]
    files: list[Path] = field(default_factory=list)
    split_description: str = ""  # how the model's training data was split
    # session → {"times_ns", "measured_n", method: predicted force} over the scored frames
    frames: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    def mae_n(self, method: str = "pointnet") -> float:
        """Overall MAE of one method (``pointnet``, ``temporal``, ``mean``,
        ``linear_displacement``, ``hooke``, ``ridge_height_map``)."""
        return float(self.metrics[method]["overall"]["mae_n"])


def _held_out_positions(model: ForceModel, session: PreparedSession) -> tuple[np.ndarray, bool]:
    """Frames of ``session`` to score and whether they were used in training.

    A session that the model's time split cut into blocks is scored on its test blocks only;
    if it has none, all its frames are scored and flagged as seen in training.
    """
    split = model.split
    everything = np.arange(session.n_used)
    if split.kind == "time" and any(split.contains(part, session.name)
                                    for part in ("train", "val", "test")):
        test = split.positions("test", session)
        return (test, False) if len(test) else (everything, True)
    return everything, split.contains("train", session.name) or split.contains("val",
                                                                             session.name)


def evaluate(model_path: str | Path, sessions: Sequence[SessionLike] | None, out_dir: str | Path,
             progress: ProgressFn | None = None) -> EvaluationReport:
    """Evaluate a model file and its baselines; writes metrics.json, report.md/.html and PNGs.

    With ``sessions=None`` the sessions in the model's recorded test split are used. Sessions
    of a time split are scored on their held-out test blocks only. Torch's thread count is
    left as the caller set it.
    """
    model = load_model(model_path)
    if not sessions:
        sessions = model.split.test
        if not sessions:
            raise EstimateError(f"{model_path} has no recorded test sessions: give the sessions "
                                "to evaluate")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    prepared = prepare_sessions(sessions, model.config, progress)

    predictions: dict[str, list[np.ndarray]] = defaultdict(list)
    measured, labels, plots, seen_in_training = [], [], [], []
    frames: dict[str, dict[str, np.ndarray]] = {}
    for k, session in enumerate(prepared):
        positions, seen = _held_out_positions(model, session)
        if seen:
            seen_in_training.append(session.name)
        per_method = {"pointnet": model.predict_session(session)}
        if model.temporal is not None:
            per_method["temporal"] = model.predict_session_temporal(session)
        per_method.update({name: b.predict_session(session)
                           for name, b in model.baselines.items()})
        per_method = {method: force[positions] for method, force in per_method.items()}
        for method, force in per_method.items():
            predictions[method].append(force)
        measured.append(session.targets_n[positions])
        frames[session.name] = {"times_ns": session.times_ns[positions],
                                "measured_n": session.targets_n[positions], **per_method}
        labels += [session.condition] * len(positions)
        plots.append(plot_session(out_dir / f"force_{k:02d}_{safe_stem(session.name)}.png",
                                  f"{session.name} ({session.condition})",
                                  session.times_ns[positions], session.targets_n[positions],
                                  per_method))
        if progress is not None:
            progress("predict", k + 1, len(prepared))

    truth = np.concatenate(measured)
    label_array = np.asarray(labels)
    metrics: dict[str, dict[str, Any]] = {}
    for method, parts in predictions.items():
        force = np.concatenate(parts)
        metrics[method] = {
            "overall": error_stats(force, truth),
            "per_condition": {label: error_stats(force[label_array == label],
                                                 truth[label_array == label])
                              for label in sorted(set(labels))}}
    plots.append(plot_scatter(out_dir / "scatter_pointnet.png", truth,
                              np.concatenate(predictions["pointnet"]), labels))

    names = [s.name for s in prepared]
    skipped = skipped_counts(prepared)
    split = model.split
    split_note = (f"training {split.describe()}"
                  + ("; scored on the held-out test blocks only" if split.kind == "time" else ""))
    notes = [f"model {Path(model_path).name} (vbfe {model.record.get('vbfe_version')}), "
             f"target {model.config.target}, {model.config.n_points} points per cloud",
             split_note,
             "baselines fitted on the training frames only; Hooke uses one fitted stiffness "
             f"k̂ = {model.baselines['hooke'].slope.round(2).tolist()} N/m for all conditions",
             f"frames skipped (empty/NaN clouds): {sum(v['skipped'] for v in skipped.values())}"]
    if model.temporal is not None:
        notes.append(f"temporal model: PointNet encoder over the rest frame and a causal window "
                     f"of {model.config.temporal_frames} frames, offsets "
                     f"{model.config.temporal_window} frames back")
    if seen_in_training:
        notes.append(f"WARNING: {len(seen_in_training)} evaluated session(s) were used in "
                     "training; these numbers are not held-out")
    metrics_path = write_json(out_dir / "metrics.json", {
        "model": str(model_path), "sessions": names, "seen_in_training": seen_in_training,
        "split": {"kind": split.kind, "gap_frames": split.gap_frames,
                  "description": split.describe()},
        "skipped": skipped, "units": "N", "metrics": metrics})
    md_path, html_path = write_tables(out_dir, metrics, notes, plots)
    return EvaluationReport(out_dir=out_dir, metrics=metrics, sessions=names,
                            seen_in_training=seen_in_training, skipped=skipped,
                            files=[metrics_path, md_path, html_path, *plots],
                            split_description=split_note, frames=frames)
