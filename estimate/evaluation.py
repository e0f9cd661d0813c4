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
import torch

from vbfe.estimate.dataset import ProgressFn, prepare_sessions, skipped_counts
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.model_file import load_model, training_sessions
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

    def mae_n(self, method: str = "pointnet") -> float:
        """Overall MAE of one method (``pointnet``, ``mean``, ``linear_displacement``, ``hooke``)."""
        return float(self.metrics[method]["overall"]["mae_n"])


def evaluate(model_path: str | Path, sessions: Sequence[SessionLike] | None, out_dir: str | Path,
             progress: ProgressFn | None = None) -> EvaluationReport:
    """Evaluate a model file and its baselines; writes metrics.json, report.md/.html and PNGs.

    With ``sessions=None`` the sessions in the model's recorded test split are used.
    """
    model = load_model(model_path)
    torch.set_num_threads(model.config.threads)
    if not sessions:
        sessions = model.record.get("split", {}).get("test", [])
        if not sessions:
            raise EstimateError(f"{model_path} has no recorded test sessions: give the sessions "
                                "to evaluate")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    prepared = prepare_sessions(sessions, model.config, progress)
    seen = set(training_sessions(model))

    predictions: dict[str, list[np.ndarray]] = defaultdict(list)
    measured, labels, plots = [], [], []
    for k, session in enumerate(prepared):
        per_method = {"pointnet": model.predict_session(session)}
        per_method.update({name: b.predict(session.displacement_m)
                           for name, b in model.baselines.items()})
        for method, force in per_method.items():
            predictions[method].append(force)
        measured.append(session.targets_n)
        labels += [session.condition] * session.n_used
        plots.append(plot_session(out_dir / f"force_{k:02d}_{safe_stem(session.name)}.png",
                                  f"{session.name} ({session.condition})", session.times_ns,
                                  session.targets_n, per_method))
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
    seen_in_training = [n for n in names if n in seen]
    skipped = skipped_counts(prepared)
    notes = [f"model {Path(model_path).name} (vbfe {model.record.get('vbfe_version')}), "
             f"target {model.config.target}, {model.config.n_points} points per cloud",
             "baselines fitted on the training sessions only; Hooke uses one fitted stiffness "
             f"k̂ = {model.baselines['hooke'].slope.round(2).tolist()} N/m for all conditions",
             f"frames skipped (empty/NaN clouds): {sum(v['skipped'] for v in skipped.values())}"]
    if seen_in_training:
        notes.append(f"WARNING: {len(seen_in_training)} evaluated session(s) were used in "
                     "training; these numbers are not held-out")
    metrics_path = write_json(out_dir / "metrics.json", {
        "model": str(model_path), "sessions": names, "seen_in_training": seen_in_training,
        "skipped": skipped, "units": "N", "metrics": metrics})
    md_path, html_path = write_tables(out_dir, metrics, notes, plots)
    return EvaluationReport(out_dir=out_dir, metrics=metrics, sessions=names,
                            seen_in_training=seen_in_training, skipped=skipped,
                            files=[metrics_path, md_path, html_path, *plots])
