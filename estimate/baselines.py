"""Baselines that PointNet must beat, all fitted on the training sessions only.

Every baseline maps a frame's peak surface displacement ``d`` (metres, vs the session's first
frame, see ``displacement.py``) to force as ``slope·d + intercept`` per output:

- ``mean``: the training mean force (slope 0);
- ``linear_displacement``: least-squares line of force on displacement;
- ``hooke``: ``F = k̂·d`` with one stiffness ``k̂`` (N/m) fitted by least squares over all
  training sessions; the per-condition stiffness is *not* given to it.

Frames without a displacement (NaN) are left out of fitting and predicted with ``d = 0``.
An affine estimator may read another per-frame displacement (``feature``): the candidate
``hooke_texture_3d`` (``candidates.py``) reads the 3D displacement tracked in the texture.

- ``mlp_displacement_history``: a small MLP on the causal window of peak displacements
  (``history_baseline.py``); left out when ``[train] history_frames`` is 0.

The estimators that compete to be shipped (PointNet, the temporal model, ridge and CNN on the
depth-change image) are in ``candidates.py``; a shipped model that loses to one of these
baselines on validation is reported as such.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vbfe.common.errors import EstimateError
from vbfe.estimate.dataset import PreparedSession
from vbfe.estimate.history_baseline import HistoryBaseline, fit_history

FEATURES = ("displacement_m", "texture_displacement_m")  # PreparedSession's displacements


@dataclass(frozen=True)
class AffineBaseline:
    """Force = slope·displacement + intercept, one (slope, intercept) per output (newtons);
    the displacement is the prepared session's ``feature``."""

    name: str
    slope: np.ndarray
    intercept: np.ndarray
    feature: str = FEATURES[0]

    def predict(self, displacement_m: np.ndarray) -> np.ndarray:
        """Predicted force (frames × outputs) from peak displacements (frames)."""
        d = np.nan_to_num(np.asarray(displacement_m, dtype=np.float64), nan=0.0)
        return d[:, None] * self.slope + self.intercept

    def predict_session(
        self, session: PreparedSession, positions: np.ndarray | None = None
    ) -> np.ndarray:
        """Predicted force (used frames × outputs) of a prepared session."""
        d = getattr(session, self.feature)
        return self.predict(d if positions is None else d[positions])

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "slope": self.slope.tolist(),
            "intercept": self.intercept.tolist(),
            "feature": self.feature,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AffineBaseline:
        feature = d.get("feature", FEATURES[0])  # model files before the texture feature
        if feature not in FEATURES:
            raise EstimateError(
                f"estimator {d.get('name')!r} reads an unknown feature "
                f"{feature!r} (known: {', '.join(FEATURES)})"
            )
        return cls(
            d["name"], np.asarray(d["slope"], float), np.asarray(d["intercept"], float), feature
        )


Baseline = AffineBaseline | HistoryBaseline


def baseline_from_dict(d: dict[str, Any]) -> Baseline:
    """Rebuild a baseline stored by ``to_dict``."""
    return (
        HistoryBaseline.from_dict(d)
        if d.get("kind") == "history_mlp"
        else AffineBaseline.from_dict(d)
    )


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
    "mean": _fit_mean,
    "linear_displacement": _fit_linear,
    "hooke": _fit_hooke,
}


def fit_baselines(
    parts: Sequence[tuple[PreparedSession, np.ndarray]],
    history_offsets: Sequence[int] = (),
    seed: int = 0,
) -> dict[str, Baseline]:
    """Fit every baseline on the given (training) frames: (session, used-frame positions);
    the displacement-history MLP only with ``history_offsets`` (frames back, 0: the frame)."""
    d = np.concatenate([s.displacement_m[p] for s, p in parts])
    y = np.concatenate([s.targets_n[p] for s, p in parts])
    if not np.isfinite(d).any():
        raise EstimateError(
            "no training frame has a surface displacement; baselines cannot be "
            "fitted (are the clouds empty outside the first frame?)"
        )
    fitted: dict[str, Baseline] = {
        name: AffineBaseline(name, *fit(d, y)) for name, fit in FITTERS.items()
    }
    if len(history_offsets):
        history = fit_history(parts, history_offsets, seed)
        fitted[history.name] = history
    return fitted
