"""One frame to one force estimate in stages: reconstruct (downscale, rectify, match, verify,
triangulate), prepare (the model's features) and model; each stage timed.

The stages run one after the other (:meth:`FrameEstimator.estimate`) or on their own threads
(:meth:`FrameEstimator.stages` with :class:`vbfe.live.pipeline.Pipeline`; a model on the
texture's displacement reconstructs and prepares on one thread); both give the same estimates
for the same frames.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
import torch

from vbfe.calib import Calibration
from vbfe.common.errors import EstimateError
from vbfe.drivers import StereoFrame
from vbfe.estimate import ForceModel, LivePredictor
from vbfe.estimate.preparation import MIN_FRAME_POINTS, FrameFeatures
from vbfe.recon import Reconstructor, SgbmParams

STAGES = ("scale", "reconstruct", "prepare", "model")
REST_DEPTH_PERCENTILES = (0.5, 99.5)  # the rest cloud's depth span (a few stray matches aside)
_NO_BOUNDS = np.full(0, np.nan)  # LiveEstimate without an interval


def _downscaled(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` at ``size`` (width, height) by area averaging; rows averaged in pairs (the
    ``[live]`` row scale 0.5) by one weighted sum, which gives the same pixels as
    ``cv2.resize``'s ``INTER_AREA`` (both round half to even) about 10× faster."""
    height, width = image.shape[:2]
    if size == (width, height):
        return image
    if size == (width, height // 2) and height % 2 == 0:
        return cv2.addWeighted(image[0::2], 0.5, image[1::2], 0.5, 0.0)
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


@dataclass(frozen=True)
class LiveEstimate:
    """The force estimated from one frame, its prediction interval, whether the frame lies
    outside the model's training data, when it was captured and when it was ready."""

    force_n: np.ndarray  # (outputs,), NaN when the frame gave no usable cloud
    frame_seq: int
    t_frame_host_ns: int  # the frame's host arrival time (capture)
    t_ready_host_ns: int  # time.monotonic_ns() when the estimate was ready
    stage_s: tuple[float, ...]  # durations of STAGES
    n_points: int
    # (outputs,) prediction interval; not given: NaN (the model has none)
    lo_n: np.ndarray = field(default_factory=lambda: _NO_BOUNDS)
    hi_n: np.ndarray = field(default_factory=lambda: _NO_BOUNDS)
    ood: bool = False  # the frame is outside the training data
    novelty_m: float = float("nan")  # its distance from the training frames

    def __post_init__(self) -> None:
        for name in ("lo_n", "hi_n"):
            if getattr(self, name) is _NO_BOUNDS:
                object.__setattr__(self, name, np.full_like(self.force_n, np.nan, np.float64))

    @property
    def latency_s(self) -> float:
        """From frame capture (host time) to estimate."""
        return (self.t_ready_host_ns - self.t_frame_host_ns) / 1e9


@dataclass
class FrameWork:
    """A frame on its way through the stages."""

    frame: StereoFrame
    stage_s: list[float] = field(default_factory=list)
    points: np.ndarray | None = None
    colors: np.ndarray | None = None  # the points' colours (texture tracking)
    features: FrameFeatures | None = None  # None: too few points for the model


class FrameEstimator:
    """Reconstructs a frame (optionally at ``scale`` of the calibrated size, its rows at
    ``row_scale`` of that) and runs the model.

    The reconstructor (rectification maps, matcher) is built once and reused for every frame;
    the model's selected estimator reads every cloud against the run's first usable cloud
    (:class:`vbfe.estimate.live_predictor.LivePredictor`), so start with the tissue at rest; a
    network runs on ``device`` (``"cpu"`` or ``"cuda"``). On a machine with several cores the
    fringe codes are decoded on a second thread while SGBM matches. ``row_scale`` < 1
    matches fewer rows (rows averaged together) at the full width: the depth resolution, set
    by the disparity along the rows, stays; the cloud has fewer points, and the model samples
    its own few from it. With ``depth_margin_mm`` > 0 the matcher searches, from the frame
    after the rest on, only the rest cloud's depths ± that margin
    (:meth:`vbfe.recon.Reconstructor.search_depths`: fewer disparities, the same extent).
    ``protocol`` picks the model's interval of that protocol for the bounds (``None``: pooled).
    """

    def __init__(
        self,
        model: ForceModel,
        calibration: Calibration,
        sgbm_params: SgbmParams | None = None,
        verify: bool = True,
        scale: float = 1.0,
        device: str = "cpu",
        seed: int = 0,
        row_scale: float = 1.0,
        depth_margin_mm: float = 0.0,
        protocol: str | None = None,
    ) -> None:
        for name, value in (("scale", scale), ("row scale", row_scale)):
            if not 0.1 <= value <= 1.0:
                raise EstimateError(f"live {name} must be in 0.1 … 1.0, got {value}")
        model = model.for_protocol(protocol)  # the method shipped for what is done
        self.model, self.scale, self.row_scale = model, scale, row_scale
        self.full_size = calibration.image_size
        params = sgbm_params or SgbmParams()
        if row_scale != 1.0:  # the fringe code is read on rows as far apart as before
            params = dataclasses.replace(
                params, decode_row_step=max(1, round(params.decode_row_step * row_scale))
            )
        self.reconstructor = Reconstructor(
            calibration.scaled(scale, scale * row_scale)
            if (scale, row_scale) != (1.0, 1.0)
            else calibration,
            params,
            verify=verify,
            parallel_decode=(os.cpu_count() or 1) > 1,
        )
        network = getattr(model.estimators[model.selected], "network", None)
        if network is not None:
            network.to(torch.device(device))
        self._predictor = LivePredictor(model, seed, protocol)
        self.depth_margin_mm = depth_margin_mm
        self._rest_seen = False  # the first cloud prepared (the rest) has set the search

    def describe(self) -> str:
        """One line: what is reconstructed, the stages and the thread counts used."""
        width, height = self.reconstructor.calibration.image_size
        return (
            f"reconstruct {width}x{height} of the camera's {self.full_size[0]}x"
            f"{self.full_size[1]}; stages {' -> '.join(n for n, _ in self.stages())} on "
            f"their own threads; OpenCV threads {cv2.getNumThreads()}, torch threads "
            f"{torch.get_num_threads()}"
        )

    def stages(self) -> list[tuple[str, Callable[[FrameWork], FrameWork | LiveEstimate]]]:
        """The (name, function) of each stage, in order, for a :class:`Pipeline` fed with
        :class:`FrameWork` items. A model on the texture's displacement prepares each frame on
        the thread that reconstructed it: its preparation (the optical flow) costs about as
        much as the reconstruction, and on two cores shared with other work a frame goes
        through both sooner one after the other than each overlapped with another frame's."""
        if self._predictor.tracks_texture:
            return [
                ("reconstruct+prepare", lambda work: self.prepare(self.reconstruct(work))),
                ("model", self.estimate_force),
            ]
        return [
            ("reconstruct", self.reconstruct),
            ("prepare", self.prepare),
            ("model", self.estimate_force),
        ]

    def estimate(self, frame: StereoFrame) -> LiveEstimate:
        """The force estimate of one frame, with the duration of each stage."""
        return self.estimate_force(self.prepare(self.reconstruct(FrameWork(frame))))

    def reconstruct(self, work: FrameWork) -> FrameWork:
        """Downscale (when asked) and reconstruct the frame's cloud."""
        t0 = time.perf_counter()
        size = self.reconstructor.calibration.image_size
        frame = work.frame
        left, right = (_downscaled(image, size) for image in (frame.left, frame.right))
        t1 = time.perf_counter()
        cloud = self.reconstructor.process(left, right)
        work.points, work.colors = cloud.points, cloud.colors
        work.stage_s += [t1 - t0, time.perf_counter() - t1]
        return work

    def prepare(self, work: FrameWork) -> FrameWork:
        """The model's features of the frame's cloud (none when it has too few points)."""
        t0 = time.perf_counter()
        assert work.points is not None  # reconstructed by the stage before
        if not self._rest_seen:
            self._rest_seen = True
            self._search_near(work.points)
        try:
            work.features = self._predictor.prepare(work.points, work.colors)
        except EstimateError:  # too few points inside the model's region of interest
            work.features = None
        work.stage_s.append(time.perf_counter() - t0)
        return work

    def _search_near(self, rest: np.ndarray) -> None:
        """Match only the rest cloud's depths ± ``depth_margin_mm`` from now on (nothing
        without a margin or a rest of too few points)."""
        depth_mm = rest[:, 2][np.isfinite(rest[:, 2]) & (rest[:, 2] > 0)] * 1e3
        if self.depth_margin_mm <= 0 or len(depth_mm) < MIN_FRAME_POINTS:
            return
        near, far = np.percentile(depth_mm, REST_DEPTH_PERCENTILES)
        margin = self.depth_margin_mm
        self.reconstructor.search_depths(max(float(near) - margin, 1e-3), float(far) + margin)

    def estimate_force(self, work: FrameWork) -> LiveEstimate:
        """The model's force from the prepared features (NaN without features)."""
        t0 = time.perf_counter()
        force = np.asarray(
            self._predictor.model_force(work.features)
            if work.features is not None
            else np.full(self.model.config.n_outputs, np.nan),
            np.float64,
        )
        lo, hi = self._predictor.bounds(force)
        novelty, ood = (
            self._predictor.novelty(work.features, force, lo, hi)
            if work.features is not None
            else (float("nan"), False)
        )
        t1 = time.perf_counter()
        return LiveEstimate(
            lo_n=lo,
            hi_n=hi,
            ood=ood,
            novelty_m=novelty,
            force_n=force,
            frame_seq=work.frame.seq,
            t_frame_host_ns=work.frame.t_host_ns,
            t_ready_host_ns=time.monotonic_ns(),
            stage_s=(*work.stage_s, t1 - t0),
            n_points=0 if work.points is None else len(work.points),
        )
