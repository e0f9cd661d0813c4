"""One frame to one force estimate: (downscale), reconstruct, model; each stage timed."""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from vbfe.calib.calibration import Calibration
from vbfe.drivers.samples import StereoFrame
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.inference import FramePredictor
from vbfe.estimate.model_file import ForceModel
from vbfe.recon.matching import SgbmParams
from vbfe.recon.triangulate import Reconstructor

STAGES = ("prepare", "reconstruct", "model")


@dataclass(frozen=True)
class LiveEstimate:
    """The force estimated from one frame, when it was captured and when it was ready."""

    force_n: np.ndarray  # (outputs,), NaN when the frame gave no usable cloud
    frame_seq: int
    t_frame_host_ns: int  # the frame's host arrival time (capture)
    t_ready_host_ns: int  # time.monotonic_ns() when the estimate was ready
    stage_s: tuple[float, ...]  # durations of STAGES
    n_points: int

    @property
    def latency_s(self) -> float:
        """From frame capture (host time) to estimate."""
        return (self.t_ready_host_ns - self.t_frame_host_ns) / 1e9


class FrameEstimator:
    """Reconstructs a frame (optionally at ``scale`` of the calibrated size) and runs the model.

    The reconstructor (rectification maps, matcher) is built once and reused for every frame;
    the model's selected estimator (``estimate.inference.FramePredictor``) reads every cloud
    against the run's first usable cloud, so start with the tissue at rest; a network runs on
    ``device`` (``"cpu"`` or ``"cuda"``).
    """

    def __init__(self, model: ForceModel, calibration: Calibration,
                 sgbm_params: SgbmParams | None = None, verify: bool = True, scale: float = 1.0,
                 device: str = "cpu", seed: int = 0) -> None:
        if not 0.1 <= scale <= 1.0:
            raise EstimateError(f"live scale must be in 0.1 … 1.0, got {scale}")
        self.model, self.scale = model, scale
        self.full_size = calibration.image_size
        self.reconstructor = Reconstructor(calibration.scaled(scale) if scale != 1.0
                                           else calibration, sgbm_params, verify=verify)
        network = getattr(model.estimators[model.selected], "network", None)
        if network is not None:
            network.to(torch.device(device))
        self._predictor = FramePredictor(model, seed)

    def _prepare(self, frame: StereoFrame) -> tuple[np.ndarray, np.ndarray]:
        if self.scale == 1.0:
            return frame.left, frame.right
        size = self.reconstructor.calibration.image_size
        return (cv2.resize(frame.left, size, interpolation=cv2.INTER_AREA),
                cv2.resize(frame.right, size, interpolation=cv2.INTER_AREA))

    def estimate(self, frame: StereoFrame) -> LiveEstimate:
        """The force estimate of one frame, with the duration of each stage."""
        t0 = time.perf_counter()
        left, right = self._prepare(frame)
        t1 = time.perf_counter()
        cloud = self.reconstructor.process(left, right)
        t2 = time.perf_counter()
        try:
            force = self._predictor.predict(cloud.points)
        except EstimateError:  # too few points inside the model's region of interest
            force = np.full(self.model.config.n_outputs, np.nan)
        t3 = time.perf_counter()
        return LiveEstimate(force_n=np.asarray(force, np.float64), frame_seq=frame.seq,
                            t_frame_host_ns=frame.t_host_ns, t_ready_host_ns=time.monotonic_ns(),
                            stage_s=(t1 - t0, t2 - t1, t3 - t2), n_points=len(cloud.points))
