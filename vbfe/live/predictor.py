"""Force from successive raw clouds in two steps (prepare, model), computing only what the
selected estimator reads.

The estimates are ``estimate.inference.FramePredictor``'s (same rest cloud, same random draws,
same causal window): a network (PointNet or the temporal model) reads only each frame's point
pool, so the live path skips the peak displacement and the depth-change image the other
estimators read, and draws the pool by index straight from a cloud whose points are all
finite (``roi = "all"``) instead of copying the cloud first.
"""

from __future__ import annotations

import numpy as np
import torch

from vbfe.estimate.candidates import NetworkEstimator
from vbfe.estimate.dataset import PreparedSession
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.model_file import ForceModel
from vbfe.estimate.preparation import (
    MIN_FRAME_POINTS,
    FrameFeatures,
    FramePreparer,
    crop_roi,
    sample_points,
)
from vbfe.estimate.rest_depth import RestDepth


class LivePredictor:
    """Predicts the force of successive clouds of one run with the model's selected method;
    the run's first usable cloud is its rest reference (start with the tissue at rest)."""

    def __init__(self, model: ForceModel, seed: int = 0) -> None:
        self.model = model
        estimator = model.estimators[model.selected]
        self._pool_only = isinstance(estimator, NetworkEstimator)
        # a single-frame network reads the newest pool alone: called directly
        self._network = (estimator.network.eval() if self._pool_only and not estimator.window
                         else None)
        self._device = (next(estimator.network.parameters()).device if self._pool_only
                        else None)
        self._span = max([*getattr(estimator, "window", ()), *getattr(estimator, "offsets", ())],
                         default=0)
        self._rng = np.random.default_rng(seed)
        self._preparer: FramePreparer | None = None
        self._rest: RestDepth | None = None
        self._frames: list[FrameFeatures] = []  # the rest frame, then the newest frames

    def prepare(self, points: np.ndarray) -> FrameFeatures:
        """The features of one raw cloud (N×3, may hold NaN); ``EstimateError`` when it has
        too few points inside the model's region of interest."""
        config = self.model.config
        if self._preparer is None:
            self._preparer = FramePreparer(points, config)
            if self._pool_only and config.rest_depth:
                self._rest = RestDepth(crop_roi(points, config))
        pool_size = config.n_points  # as FramePredictor draws
        if not self._pool_only:
            cropped = self._preparer.cropped(points)
            if cropped is None:
                raise _too_few()
            return self._preparer.features(cropped, pool_size, self._rng)
        if config.roi == "all" and np.isfinite(points).all():
            if len(points) < MIN_FRAME_POINTS:
                raise _too_few()
            draw = self._rng.choice(len(points), size=pool_size, replace=len(points) < pool_size)
            pool = np.asarray(points[draw], np.float64)
        else:
            cropped = self._preparer.cropped(points)
            if cropped is None:
                raise _too_few()
            pool = sample_points(cropped, pool_size, self._rng)
        cells = (config.image_cells,) * 2
        return FrameFeatures(
            pool=self._rest.with_change(pool) if self._rest else pool.astype(np.float32),
            displacement_m=float("nan"), image_sum=np.zeros(cells, np.float32),
            image_count=np.zeros(cells, np.float32))

    def model_force(self, features: FrameFeatures) -> np.ndarray:
        """Force (outputs,) of the newest prepared frame (after the frames before it)."""
        config = self.model.config
        if self._network is not None:
            points = torch.from_numpy(features.pool[None, :config.n_points])
            with torch.no_grad():
                return self._network(points.to(self._device))[0].cpu().double().numpy()
        self._frames.append(features)
        if len(self._frames) > self._span + 2:
            del self._frames[1]
        n = len(self._frames)
        session = PreparedSession.from_features(
            "live", {}, self._frames, np.arange(n), np.arange(n),
            np.zeros((n, config.n_outputs)), config, n_frames_total=n)
        return self.model.predict_session(session, positions=np.array([n - 1]))[0]


def _too_few() -> EstimateError:
    return EstimateError("the cloud has too few finite points inside the model's region of "
                         "interest; check the reconstruction or the [train] roi")
