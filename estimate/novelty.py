"""A flag on frames unlike anything a model was trained on.

A frame is described by what every estimator reads of the surface (metres): the depth-change
image pooled to ``THUMB_CELLS`` × ``THUMB_CELLS`` cells (mean change per cell), its cells sorted
from the largest change down (how much of the surface moved how far, wherever the grasp sits:
trials differ in where the tissue is taken, not only in how it deforms), the peak surface
displacement and, when the training frames had one, the peak displacement tracked in the
texture, and how densely the surface was reconstructed (the log of the points in the region
of interest: a wet, glossy or cross-lit surface loses matches before it misleads an estimator).
Each feature but the image's is weighted so that its spread over the training frames equals the
image cells' (distances stay in metres of depth change, and no feature drowns the others). Its
novelty is the distance to its ``K``-th nearest training frame. The threshold is
the ``QUANTILE`` of the same distance for the training frames themselves, each measured against
the training frames of *other* groups (other sessions; one session: other blocks in time), so
a frame of a new trial like the training ones passes about as often as a training frame does,
and neighbouring near-copies of a frame do not make it look familiar. A frame whose texture is
lost while the training frames had one is always flagged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from vbfe.common.errors import EstimateError
from vbfe.estimate.dataset import PreparedSession
from vbfe.estimate.preparation import FrameFeatures

THUMB_CELLS = 8
K = 3
QUANTILE = 0.99
MAX_REFERENCE = 4000  # training frames kept as the reference (evenly spaced)
TIME_GROUPS = 5  # one training session: groups of contiguous frames
_CHUNK = 512


def _vectors(
    image_sum: np.ndarray,
    image_count: np.ndarray,
    displacement_m: np.ndarray,
    texture_m: np.ndarray | None,
    density: bool,
) -> np.ndarray:
    """Frames × features (see the module's description), unweighted."""
    total = np.asarray(image_sum, np.float64)
    count = np.asarray(image_count, np.float64)
    cells = total.shape[-1]
    size = THUMB_CELLS if cells % THUMB_CELLS == 0 else cells
    block = cells // size
    shape = (len(total), size, block, size, block)
    total = total.reshape(shape).sum(axis=(2, 4))
    count = count.reshape(shape).sum(axis=(2, 4))
    thumb = np.where(count > 0, total / np.maximum(count, 1), 0.0).reshape(len(total), -1)
    columns = [
        -np.sort(-thumb, axis=1),
        np.nan_to_num(np.asarray(displacement_m, np.float64))[:, None],
    ]
    if texture_m is not None:
        columns.append(np.asarray(texture_m, np.float64)[:, None])  # NaN kept: lost texture
    if density:
        points = np.asarray(image_count, np.float64).reshape(len(total), -1).sum(axis=1)
        columns.append(np.log(np.maximum(points, 1.0))[:, None])
    return np.concatenate(columns, axis=1)


def _weights(vectors: np.ndarray) -> np.ndarray:
    """Per feature: 1 for the image's cells, else the cells' spread over its own (see the
    module's description; 1 for a feature that never varies)."""
    cells = THUMB_CELLS * THUMB_CELLS
    spread = np.nanstd(vectors, axis=0)
    scale = float(np.nanstd(vectors[:, :cells]))
    weights = np.where(spread > 0, scale / np.where(spread > 0, spread, 1.0), 1.0)
    weights[:cells] = 1.0
    return weights


def _kth_distance(queries: np.ndarray, reference: np.ndarray, k: int) -> np.ndarray:
    """Distance of each query to its ``k``-th nearest reference row (inf with a NaN feature
    or too few reference rows)."""
    out = np.full(len(queries), np.inf)
    if len(reference) < k:
        return out
    ref_sq = (reference**2).sum(axis=1)
    for start in range(0, len(queries), _CHUNK):
        q = queries[start : start + _CHUNK]
        squared = (q**2).sum(axis=1)[:, None] + ref_sq[None] - 2 * q @ reference.T
        kth = np.partition(np.maximum(squared, 0), k - 1, axis=1)[:, k - 1]
        out[start : start + _CHUNK] = np.where(np.isfinite(kth), np.sqrt(kth), np.inf)
    return out


@dataclass
class NoveltyFlag:
    """Distance of a frame's features to the training frames and the threshold over which a
    frame is flagged as outside the training data."""

    reference: np.ndarray  # training frames × features, weighted
    threshold: float  # metres
    texture: bool  # the features include the texture's displacement
    k: int = K
    density: bool = False  # the features include the reconstruction's density
    weights: np.ndarray | None = None  # per feature (None: all 1)

    def session_features(self, session: PreparedSession, positions: np.ndarray) -> np.ndarray:
        """Weighted feature vectors of a prepared session's used frames at ``positions``."""
        return self._weighted(
            _vectors(
                session.image_sum[positions],
                session.image_count[positions],
                session.displacement_m[positions],
                session.texture_displacement_m[positions] if self.texture else None,
                self.density,
            )
        )

    def _weighted(self, vectors: np.ndarray) -> np.ndarray:
        return vectors if self.weights is None else vectors * self.weights

    def frame_distance(self, features: FrameFeatures) -> float:
        """Novelty (m) of one frame's features (``vbfe live``)."""
        vector = _vectors(
            features.image_sum[None],
            features.image_count[None],
            np.array([features.displacement_m]),
            np.array([features.texture_displacement_m]) if self.texture else None,
            self.density,
        )
        return float(_kth_distance(self._weighted(vector), self.reference, self.k)[0])

    def distances(self, session: PreparedSession, positions: np.ndarray) -> np.ndarray:
        """Novelty (m) of the frames at ``positions``."""
        return _kth_distance(self.session_features(session, positions), self.reference, self.k)

    def to_dict(self) -> dict[str, Any]:
        return {
            "reference": torch.from_numpy(self.reference.astype(np.float32)),
            "threshold_m": self.threshold,
            "texture": self.texture,
            "k": self.k,
            "density": self.density,
            **({} if self.weights is None else {"weights": [float(w) for w in self.weights]}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NoveltyFlag:
        reference = d["reference"]
        if not isinstance(reference, torch.Tensor) or reference.ndim != 2:
            raise EstimateError("the novelty reference is not a frames × features tensor")
        weights = np.asarray(d["weights"], np.float64) if "weights" in d else None
        if weights is not None and weights.shape != (reference.shape[1],):
            raise EstimateError("the novelty weights do not match its reference's features")
        return cls(
            reference.double().numpy(),
            float(d["threshold_m"]),
            bool(d["texture"]),
            int(d["k"]),
            bool(d.get("density", False)),  # model files before it: without
            weights,
        )


def fit_novelty(parts: Sequence[tuple[PreparedSession, np.ndarray]]) -> NoveltyFlag | None:
    """The flag of the training frames (session, positions); ``None`` with fewer than two
    groups of frames to measure each against."""
    texture = bool(
        np.concatenate([np.isfinite(s.texture_displacement_m[p]) for s, p in parts]).all()
    )
    probe = NoveltyFlag(np.zeros((0, 0)), np.inf, texture, density=True)
    raw = np.concatenate([probe.session_features(s, p) for s, p in parts])
    probe.weights = _weights(raw)
    vectors = probe._weighted(raw)
    if len(parts) >= 2:
        groups = np.concatenate([np.full(len(p), g) for g, (_, p) in enumerate(parts)])
    else:
        groups = np.arange(len(vectors)) * TIME_GROUPS // max(len(vectors), 1)
    if len(set(groups.tolist())) < 2 or len(vectors) < 2 * K:
        return None
    own = np.concatenate(
        [_kth_distance(vectors[groups == g], vectors[groups != g], K) for g in np.unique(groups)]
    )
    finite = own[np.isfinite(own)]
    if not len(finite):
        return None
    keep = np.linspace(0, len(vectors) - 1, min(len(vectors), MAX_REFERENCE)).round().astype(int)
    return NoveltyFlag(
        vectors[keep],
        float(np.quantile(finite, QUANTILE)),
        texture,
        density=True,
        weights=probe.weights,
    )
