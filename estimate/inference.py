"""Force from raw clouds, one at a time, with the model a training run selected (vbfe live).

The run's first usable cloud is its rest reference (start with the tissue at rest); every
cloud goes through the same ``FramePreparer`` as in training, and the selected estimator reads
the newest frame (the temporal model: its causal window, frames before the run's start
repeating the rest frame, as in training).
"""

from __future__ import annotations

import numpy as np

from vbfe.common.errors import EstimateError
from vbfe.estimate.candidates import reads_texture
from vbfe.estimate.dataset import PreparedSession
from vbfe.estimate.model_file import ForceModel
from vbfe.estimate.preparation import FrameFeatures, FramePreparer


class FramePredictor:
    """Predicts the force of successive clouds of one run with the model's selected method.

    The first cloud given is the run's rest reference; give the clouds in time order (methods
    with a temporal window read the frames before each one).

    :param model: a trained model (:func:`vbfe.estimate.model_file.load_model`).
    :param seed: seeds the draws of each cloud's point pool (predictions are reproducible).
    """

    def __init__(self, model: ForceModel, seed: int = 0) -> None:
        self.model = model
        self.method = model.selected
        estimator = model.estimators[model.selected]
        self._span = max(
            [*getattr(estimator, "window", ()), *getattr(estimator, "offsets", ())], default=0
        )
        self.rng = np.random.default_rng(seed)  # the draws of every cloud's point pool
        self._texture = reads_texture(estimator)  # only then is the texture tracked
        self._preparer: FramePreparer | None = None
        self._frames: list[FrameFeatures] = []  # the rest frame, then the newest frames

    @property
    def n_outputs(self) -> int:
        """Values per prediction (1 for the force magnitude or one axis, 3 for the three axes)."""
        return self.model.config.n_outputs

    def preparer(self, points: np.ndarray, colors: np.ndarray | None = None) -> FramePreparer:
        """The run's preparer; the first cloud given (with its colours) becomes the rest
        reference."""
        if self._preparer is None:
            preparer = FramePreparer(points, self.model.config, colors, self._texture)
            if self._texture and preparer.texture is None:
                raise EstimateError(
                    f"the model's {self.method} reads the tissue's texture, but "
                    f"{preparer.texture_reason}; use a model trained without it "
                    "(vbfe train --model ...)"
                )
            self._preparer = preparer
        return self._preparer

    def cropped(self, points: np.ndarray) -> np.ndarray:
        """The model's region of interest of one raw cloud (N×3, may hold NaN);
        ``EstimateError`` when too few points are in it."""
        cropped = self.preparer(points).cropped(points)
        if cropped is None:
            raise too_few_points()
        return cropped

    def features(self, points: np.ndarray, colors: np.ndarray | None = None) -> FrameFeatures:
        """The features of one raw cloud, as in training (the texture displacement only when
        the selected method reads it).

        :param points: the cloud (N×3, metres, may hold NaN).
        :param colors: its points' colours (N×3) or ``None``.
        :raises EstimateError: too few points inside the model's region of interest, or the
            method reads a texture this cloud has not.
        """
        preparer = self.preparer(points, colors)
        return preparer.features(
            self.cropped(points), self.model.config.n_points, self.rng, points, colors
        )

    def predict_features(self, features: FrameFeatures) -> np.ndarray:
        """The force of the newest frame's features (after the frames before it).

        :param features: from :meth:`features`.
        :returns: the force, one value per output of the model (``n_outputs``), newtons.
        """
        self._frames.append(features)
        if len(self._frames) > self._span + 2:
            del self._frames[1]
        n = len(self._frames)
        session = PreparedSession.from_features(
            "live",
            {},
            self._frames,
            np.arange(n),
            np.arange(n),
            np.zeros((n, self.n_outputs)),
            self.model.config,
            n_frames_total=n,
        )
        return self.model.predict_session(session, positions=np.array([n - 1]))[0]

    def predict(self, points: np.ndarray, colors: np.ndarray | None = None) -> np.ndarray:
        """The force of one raw cloud, the next of the run.

        :param points: the cloud (N×3, metres, may hold NaN).
        :param colors: its points' colours (N×3) or ``None``.
        :returns: the force, one value per output of the model (``n_outputs``), newtons.
        :raises EstimateError: too few points inside the model's region of interest, or the
            method reads a texture this cloud has not.
        """
        return self.predict_features(self.features(points, colors))


def too_few_points() -> EstimateError:
    """The error for a cloud with too few points inside the model's region of interest."""
    return EstimateError(
        "the cloud has too few finite points inside the model's region of "
        "interest; check the reconstruction or the [train] roi"
    )
