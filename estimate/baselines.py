"""Baselines that PointNet must beat, all fitted on the training sessions only.

Every baseline maps a frame's peak surface displacement ``d`` (metres, vs the session's first
frame, see ``displacement.py``) to force as ``slope·d + intercept`` per output:

- ``mean``: the training mean force (slope 0);
- ``linear_displacement``: least-squares line of force on displacement;
- ``hooke``: ``F = k̂·d`` with one stiffness ``k̂`` (N/m) fitted by least squares over all
  training sessions; the per-condition stiffness is *not* given to it.

Frames without a displacement (NaN) are left out of fitting and predicted with ``d = 0``.

- ``mlp_displacement_history``: a small MLP on the causal window of peak displacements
  (``history_baseline.py``); left out when ``[train] history_frames`` is 0.
- ``ridge_height_map``: ridge regression on the frame's downsampled height map relative to the
  rest (first) frame (``PreparedSession.heights_m``, cells² values), columns standardised on the
  training frames, penalty chosen by cross-validation over the training sessions (contiguous
  blocks when there is one).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Union

import numpy as np

from vbfe.estimate.dataset import PreparedSession
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.history_baseline import HistoryBaseline, fit_history


@dataclass(frozen=True)
class AffineBaseline:
    """Force = slope·displacement + intercept, one (slope, intercept) per output (newtons)."""

    name: str
    slope: np.ndarray
    intercept: np.ndarray

    def predict(self, displacement_m: np.ndarray) -> np.ndarray:
        """Predicted force (frames × outputs) from peak displacements (frames)."""
        d = np.nan_to_num(np.asarray(displacement_m, dtype=np.float64), nan=0.0)
        return d[:, None] * self.slope + self.intercept

    def predict_session(self, session: PreparedSession) -> np.ndarray:
        """Predicted force (used frames × outputs) of a prepared session."""
        return self.predict(session.displacement_m)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "slope": self.slope.tolist(),
                "intercept": self.intercept.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "AffineBaseline":
        return cls(d["name"], np.asarray(d["slope"], float), np.asarray(d["intercept"], float))


@dataclass(frozen=True)
class RidgeBaseline:
    """Force = ((heights − mean) / scale) · weights + intercept, on the height map of a frame."""

    name: str
    mean: np.ndarray  # cells²
    scale: np.ndarray  # cells²
    weights: np.ndarray  # cells² × outputs
    intercept: np.ndarray  # outputs
    alpha: float

    def predict(self, heights_m: np.ndarray) -> np.ndarray:
        """Predicted force (frames × outputs) from height maps (frames × cells²)."""
        return ((np.asarray(heights_m, float) - self.mean) / self.scale) @ self.weights \
            + self.intercept

    def predict_session(self, session: PreparedSession) -> np.ndarray:
        """Predicted force (used frames × outputs) of a prepared session."""
        return self.predict(session.heights_m)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "kind": "ridge", "mean": self.mean.tolist(),
                "scale": self.scale.tolist(), "weights": self.weights.tolist(),
                "intercept": self.intercept.tolist(), "alpha": self.alpha}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RidgeBaseline":
        return cls(d["name"], *(np.asarray(d[k], float) for k in
                                ("mean", "scale", "weights", "intercept")), float(d["alpha"]))


Baseline = Union[AffineBaseline, RidgeBaseline, HistoryBaseline]
_KINDS = {"ridge": RidgeBaseline, "history_mlp": HistoryBaseline}


def baseline_from_dict(d: dict[str, Any]) -> Baseline:
    """Rebuild a baseline stored by ``to_dict``."""
    return _KINDS.get(d.get("kind"), AffineBaseline).from_dict(d)


RIDGE_FOLDS = 5


def _ridge_solve(x: np.ndarray, y: np.ndarray, alphas: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Column means/scales of ``x``, the mean of ``y`` and ridge weights for every alpha."""
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale = np.where(scale > 1e-12, scale, 1.0)
    u, sv, vt = np.linalg.svd((x - mean) / scale, full_matrices=False)
    y_mean = y.mean(axis=0)
    uty = u.T @ (y - y_mean)
    weights = [vt.T @ ((sv / (sv ** 2 + a))[:, None] * uty) for a in alphas]
    return np.stack([mean, scale]), y_mean, weights


def fit_ridge(heights: np.ndarray, y: np.ndarray,
              groups: np.ndarray | None = None) -> RidgeBaseline:
    """Ridge regression on height maps; the penalty is chosen by blocked cross-validation.

    With frames from two or more sessions (``groups``: a session id per frame) each session is
    one fold, so the penalty is the one that carries over to a session it did not see (the
    use it is scored on); otherwise the frames are cut into ``RIDGE_FOLDS`` contiguous folds
    (neighbouring frames are nearly copies of each other, so shuffled folds would favour
    overfitting).
    """
    alphas = np.logspace(-2, 5, 22) * len(heights) / max(heights.shape[1], 1)
    frames = np.arange(len(heights))
    if groups is not None and len(np.unique(groups)) >= 2:
        folds = [frames[groups == g] for g in np.unique(groups)]
    else:
        folds = np.array_split(frames, min(RIDGE_FOLDS, len(heights)))
    errors = np.zeros(len(alphas))
    for fold in folds:
        fit = np.setdiff1d(frames, fold)
        if len(fit) < 2:
            continue
        (mean, scale), y_mean, weights = _ridge_solve(heights[fit], y[fit], alphas)
        x = (heights[fold] - mean) / scale
        errors += [float(((x @ w + y_mean - y[fold]) ** 2).sum()) for w in weights]
    best = int(np.argmin(errors))
    (mean, scale), y_mean, weights = _ridge_solve(heights, y, alphas[best:best + 1])
    return RidgeBaseline("ridge_height_map", mean, scale, weights[0], y_mean,
                         float(alphas[best]))


def _fit_mean(d: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.zeros(y.shape[1]), y.mean(axis=0)


def _finite(d: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    usable = np.isfinite(d)
    return d[usable], y[usable]


def _fit_linear(d: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d, y = _finite(d, y)
    design = np.column_stack([d, np.ones_like(d)])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    return coef[0], coef[1]


def _fit_hooke(d: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d, y = _finite(d, y)
    denominator = float(d @ d)
    slope = (d @ y) / denominator if denominator > 0 else np.zeros(y.shape[1])
    return slope, np.zeros(y.shape[1])


FITTERS: dict[str, Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]] = {
    "mean": _fit_mean, "linear_displacement": _fit_linear, "hooke": _fit_hooke}


def fit_baselines(parts: Sequence[tuple[PreparedSession, np.ndarray]],
                  history_offsets: Sequence[int] = (), seed: int = 0) -> dict[str, Baseline]:
    """Fit every baseline on the given (training) frames: (session, used-frame positions);
    the displacement-history MLP only with ``history_offsets`` (frames back, 0: the frame)."""
    d = np.concatenate([s.displacement_m[p] for s, p in parts])
    y = np.concatenate([s.targets_n[p] for s, p in parts])
    if not np.isfinite(d).any():
        raise EstimateError("no training frame has a surface displacement; baselines cannot be "
                            "fitted (are the clouds empty outside the first frame?)")
    fitted: dict[str, Baseline] = {name: AffineBaseline(name, *fit(d, y))
                                   for name, fit in FITTERS.items()}
    sessions = np.concatenate([np.full(len(p), k) for k, (_, p) in enumerate(parts)])
    fitted["ridge_height_map"] = fit_ridge(np.concatenate([s.heights_m[p] for s, p in parts]), y,
                                           sessions)
    if len(history_offsets):
        history = fit_history(parts, history_offsets, seed)
        fitted[history.name] = history
    return fitted
