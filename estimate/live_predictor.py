"""Force from successive raw clouds in two steps (prepare, model), computing only what the
selected estimator reads.

The estimates are :class:`~vbfe.estimate.inference.FramePredictor`'s (same rest cloud, same
random draws, same causal window): a network (PointNet or the temporal model) reads only each
frame's point pool, so the live path skips the peak displacement and the depth-change image the
other estimators read, and draws the pool (the one draw, ``preparation.sample_points``) straight
from a cloud whose points are all finite (``roi = "all"``) instead of copying the cloud first.
When the model carries a flag of frames outside the training data (``estimate.novelty``) or a
check against Hooke's law (``estimate.disagreement``) every frame's full features are computed,
since the flag reads the depth-change image and the displacement, the check the displacement.
Likewise Hooke's law on the texture's displacement (without either) reads only that: the live
path computes it alone, by the same ``TextureMotion`` as in training.
"""

from __future__ import annotations

import numpy as np
import torch

from vbfe.common.errors import EstimateError
from vbfe.estimate import cell_passes
from vbfe.estimate.baselines import AffineBaseline
from vbfe.estimate.candidates import TEXTURE_FEATURE, NetworkEstimator, reads_texture
from vbfe.estimate.inference import FramePredictor, too_few_points
from vbfe.estimate.model_file import ForceModel
from vbfe.estimate.preparation import (
    MIN_FRAME_POINTS,
    FrameFeatures,
    physical_estimate,
    sample_points,
)


def _finite_rows(points: np.ndarray) -> int:
    """Rows of ``points`` with every value finite (a sum first, ~10× cheaper: a live cloud
    holds only its matched pixels)."""
    if np.isfinite(points.sum()):
        return len(points)
    return int(np.count_nonzero(np.isfinite(points).all(axis=1)))


class LivePredictor:
    """Predicts the force of successive clouds of one run with the model's selected method;
    the run's first usable cloud is its rest reference (start with the tissue at rest).

    :param model: the trained model.
    :param seed: seed of the point draws.
    :param protocol: what the operator does: the method shipped for that protocol and its
        interval (``None``: the method of a session stating no protocol, as ``vbfe evaluate``
        and training take one, and the interval pooled over the protocols).
    :raises EstimateError: the model calibrated no interval of ``protocol``.
    """

    def __init__(self, model: ForceModel, seed: int = 0, protocol: str | None = None) -> None:
        model = model.for_protocol(protocol)  # as evaluate takes a session stating none
        cell_passes.warm_up()  # the first (rest) frame prepared without waiting for them
        self.model = model
        self.protocol = protocol
        self._full = FramePredictor(model, seed)  # its rest cloud, draws and causal window
        estimator = model.estimators[model.selected]
        network = isinstance(estimator, NetworkEstimator)
        flags = model.novelty is not None or model.disagreement is not None
        self._pool_only = network and not flags
        self._texture_only = getattr(estimator, "feature", None) == TEXTURE_FEATURE and not flags
        # a single-frame network reads the newest pool alone: called directly
        self._network: torch.nn.Module | None = None
        self._device: torch.device | None = None
        if isinstance(estimator, NetworkEstimator):
            if not estimator.window:
                self._network = estimator.network.eval()
            self._device = next(estimator.network.parameters()).device
        self._interval = model.interval()
        known = sorted(self._interval.protocols) if self._interval is not None else []
        if protocol and protocol not in known:
            raise EstimateError(
                f"[live] protocol {protocol!r}: the model has no interval of it ("
                + (f"its protocols: {', '.join(known)}" if known else "one pooled interval")
                + "); name one of them or leave protocol empty"
            )

    @property
    def tracks_texture(self) -> bool:
        """The selected estimator reads the texture's displacement: preparing a frame then
        costs about as much as reconstructing it (the optical flow)."""
        return reads_texture(self.model.estimators[self.model.selected])

    def prepare(self, points: np.ndarray, colors: np.ndarray | None = None) -> FrameFeatures:
        """The features of one raw cloud (N×3, may hold NaN; its points' colours, N×3 or
        ``None``); ``EstimateError`` when it has too few points inside the model's region of
        interest."""
        if self._texture_only:
            preparer = self._full.preparer(points, colors)
            if self.model.config.roi != "all":  # a frame the full path refuses is refused
                self._full.cropped(points)
            elif _finite_rows(points) < MIN_FRAME_POINTS:
                raise too_few_points()
            return preparer.texture_features(points, colors)
        if not self._pool_only:
            return self._full.features(points, colors)
        preparer = self._full.preparer(points)
        pool_size = self.model.config.n_points  # as FramePredictor draws
        if self.model.config.roi == "all" and _finite_rows(points) == len(points):
            if len(points) < MIN_FRAME_POINTS:
                raise too_few_points()
            cloud = points  # every point finite and inside: no copy of the cloud
        else:
            cloud = self._full.cropped(points)
        pool = np.asarray(sample_points(cloud, pool_size, self._full.rng), np.float64)
        return preparer.pool_features(pool)

    def model_force(self, features: FrameFeatures) -> np.ndarray:
        """Force (outputs,) of the newest prepared frame (after the frames before it)."""
        if self._network is None:
            return self._full.predict_features(features)
        points = torch.from_numpy(features.pool[None, : self.model.config.n_points])
        with torch.no_grad():
            force = self._network(points.to(self._device))[0].cpu().double().numpy()
        return physical_estimate(force, self.model.config.target)

    def bounds(self, force_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The prediction interval (lo, hi) of an estimate (NaN: the model has none)."""
        if self._interval is None:
            return np.full_like(force_n, np.nan), np.full_like(force_n, np.nan)
        return self._interval.bounds(force_n, self.protocol)

    def novelty(
        self, features: FrameFeatures, force_n: np.ndarray, lo_n: np.ndarray, hi_n: np.ndarray
    ) -> tuple[float, bool]:
        """A frame's distance from the training data (m; NaN: the model has no flag) and
        whether its estimate ``force_n`` with its interval ``lo_n``..``hi_n`` (:meth:`bounds`)
        is flagged (:meth:`ForceModel.flagged`: outside the training data, or off Hooke's
        law)."""
        model = self.model
        distance = float("nan") if model.novelty is None else model.novelty.frame_distance(features)
        forces = {
            model.selected: np.asarray(force_n, np.float64)[None],
            f"{model.selected}_lo": np.asarray(lo_n)[None],
            f"{model.selected}_hi": np.asarray(hi_n)[None],
        }
        check = model.disagreement
        if check is not None:
            reference = model.estimators[check.reference]
            if not isinstance(reference, AffineBaseline):
                raise EstimateError(f"the check's reference {check.reference} is not affine")
            displacement = np.array([getattr(features, reference.feature)])
            forces[check.reference] = physical_estimate(
                reference.predict(displacement), model.config.target
            )
        return distance, bool(model.flagged(np.array([distance]), forces)[0])
