"""Prediction intervals calibrated on held-out residuals (split conformal).

Every method's interval comes from its errors on frames it was not fitted on: the validation
part, or the out-of-fold predictions of blocked folds of the sessions the fit saw (when the
validation part is small, and for the methods quick to refit: ``training.py``); folds and
parts hold out whole sessions or contiguous blocks in time,
never single frames, so the residuals are as far from the fit as a new trial is. The score of
a frame is ``|measured − predicted| / difficulty`` per output; the interval of a new frame is
``predicted ± q · difficulty`` with ``q`` the ``⌈(n + 1)·coverage⌉``-th smallest of the ``n``
calibration scores (infinite when ``n`` is too small for the coverage). Difficulty ``"none"``
is 1 (a constant width); ``"force"`` is ``floor + |predicted|`` (errors grow with the force;
``floor`` the median ``|predicted|`` of the calibration frames), so the band widens under load.

When the calibration frames come from several protocols (pull-and-hold trials and freehand
ones, whose errors differ), each protocol also gets its own quantile from its own frames
(Mondrian conformal prediction: coverage holds within each protocol, not only over their
mix), when they come from at least ``MIN_PROTOCOL_SESSIONS`` sessions: trials of a protocol
differ (tissue, speed), and one trial cannot stand for the others. A protocol of fewer
sessions gets the largest of its sessions' own quantiles: trials exchangeable, a new trial's
quantile exceeds the largest of ``m`` trials' with probability ``1/(m + 1)`` (the pooled one is
no guide: other protocols' held-out sessions may be of conditions no other session shows, their
errors those of an extrapolation). A frame of a protocol without its own quantile (too few
frames, or not stated) gets the pooled one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vbfe.common.errors import EstimateError
from vbfe.estimate.train_config import INTERVAL_SCALES as SCALES

MIN_PROTOCOL_SESSIONS = 3  # a protocol's own quantile needs frames of this many sessions


@dataclass(frozen=True)
class ConformalInterval:
    """Calibrated interval of one method.

    ``quantile``: per output, in units of the difficulty, pooled over every calibration frame;
    ``protocols``: the same from each protocol's frames alone (when they were of several);
    ``source``: where the calibration residuals came from (``"validation"`` or ``"training
    folds"``).
    """

    coverage: float
    quantile: np.ndarray
    scale: str = "none"
    floor_n: float = 1.0
    n_calibration: int = 0
    source: str = "validation"
    protocols: dict[str, np.ndarray] = field(default_factory=dict)

    def difficulty(self, predicted_n: np.ndarray) -> np.ndarray:
        """Per frame and output, the factor the quantile is multiplied by."""
        predicted = np.asarray(predicted_n, np.float64)
        if self.scale == "force":
            return self.floor_n + np.abs(predicted)
        return np.ones_like(predicted)

    def bounds(
        self, predicted_n: np.ndarray, protocol: str | np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi), each shaped like ``predicted_n`` (frames × outputs, or outputs).

        :param protocol: the frames' protocol (one for all, or one per frame): its own
            quantile when calibrated, else (and with ``None``) the pooled one.
        """
        predicted = np.asarray(predicted_n, np.float64)
        quantile = np.broadcast_to(self.quantile, predicted.shape).copy()
        if protocol is not None and self.protocols:
            labels = np.broadcast_to(np.asarray(protocol, dtype=object), predicted.shape[:-1])
            for name, q in self.protocols.items():
                quantile[labels == name] = q
        half = quantile * self.difficulty(predicted)
        return predicted - half, predicted + half

    def to_dict(self) -> dict[str, Any]:
        return {
            "coverage": self.coverage,
            "quantile": [float(q) for q in self.quantile],
            "scale": self.scale,
            "floor_n": self.floor_n,
            "n_calibration": self.n_calibration,
            "source": self.source,
            "protocols": {k: [float(q) for q in v] for k, v in self.protocols.items()},
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ConformalInterval:
        if d.get("scale", "none") not in SCALES or not 0 < float(d["coverage"]) < 1:
            raise EstimateError(f"interval {d!r} has an unknown scale or a coverage not in (0, 1)")
        return cls(
            float(d["coverage"]),
            np.asarray(d["quantile"], np.float64),
            d.get("scale", "none"),
            float(d.get("floor_n", 1.0)),
            int(d.get("n_calibration", 0)),
            str(d.get("source", "validation")),
            {k: np.asarray(v, np.float64) for k, v in d.get("protocols", {}).items()},
        )


def _quantile(scores: np.ndarray, coverage: float) -> np.ndarray:
    """The ``⌈(n + 1)·coverage⌉``-th smallest score per output (infinite when n is too small)."""
    n = len(scores)
    rank = math.ceil((n + 1) * coverage)
    return np.sort(scores, axis=0)[rank - 1] if rank <= n else np.full(scores.shape[1], np.inf)


def calibrate(
    predicted_n: np.ndarray,
    measured_n: np.ndarray,
    coverage: float,
    scale: str = "none",
    source: str = "validation",
    protocols: np.ndarray | None = None,
    sessions: np.ndarray | None = None,
) -> ConformalInterval:
    """The interval whose ``coverage`` holds on frames exchangeable with these held-out ones
    (frames × outputs each; ``protocols`` and ``sessions``: each frame's protocol and session,
    for per-protocol quantiles). ``EstimateError`` for a coverage outside (0, 1) or an unknown
    ``scale``."""
    if not 0 < coverage < 1:
        raise EstimateError(f"interval coverage {coverage} must be in (0, 1), e.g. 0.9")
    if scale not in SCALES:
        raise EstimateError(f"interval scale {scale!r} must be one of {SCALES}")
    predicted = np.asarray(predicted_n, np.float64)
    measured = np.asarray(measured_n, np.float64)
    n = len(predicted)
    floor = float(np.median(np.abs(predicted))) if n else 1.0
    interval = ConformalInterval(
        coverage, np.zeros(predicted.shape[1]), scale, max(floor, 1e-3), n, source
    )
    scores = np.abs(measured - predicted) / interval.difficulty(predicted)
    by_protocol: dict[str, np.ndarray] = {}
    labels = np.asarray(protocols if protocols is not None else [""] * n, dtype=object)
    trials = np.asarray(sessions if sessions is not None else np.arange(n), dtype=object)
    pooled = _quantile(scores, coverage)
    if len(set(labels)) > 1:
        for name in sorted(set(labels)):
            rows = labels == name
            seen = set(trials[rows])
            if len(seen) >= MIN_PROTOCOL_SESSIONS:
                q = _quantile(scores[rows], coverage)
            else:  # too few to pool: the worst
                q = np.max(
                    [_quantile(scores[rows & (trials == t)], coverage) for t in seen], axis=0
                )
            if np.isfinite(q).all():
                by_protocol[str(name)] = q
    return ConformalInterval(
        coverage,
        pooled,
        scale,
        interval.floor_n,
        n,
        source,
        by_protocol,
    )


def coverage_width(lo_n: np.ndarray, hi_n: np.ndarray, measured_n: np.ndarray) -> dict[str, float]:
    """Share of (frame, output) values inside their interval and the interval's mean width."""
    inside = (measured_n >= lo_n) & (measured_n <= hi_n)
    return {
        "interval_coverage": float(inside.mean()) if inside.size else float("nan"),
        "interval_width_n": float(np.mean(hi_n - lo_n)) if inside.size else float("nan"),
    }
