"""Accuracy of a reconstruction against ground truth (the simulated bench renders it)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from vbfe.recon.errors import ReconError
from vbfe.recon.triangulate import FrameCloud

BAD_PIXEL_PX = 1.0


@dataclass(frozen=True)
class AccuracyReport:
    """Valid fraction of the truth-covered pixels, depth errors (m) and bad-pixel rate."""

    valid_fraction: float
    n_valid: int
    median_abs_depth_error_m: float
    p95_abs_depth_error_m: float
    bad_pixel_rate: float  # share of reconstructed pixels with |disparity error| > threshold

    def as_dict(self) -> dict[str, float]:
        """The numbers as a plain dict (for printing or JSON)."""
        return asdict(self)


def evaluate_against_truth(estimate: FrameCloud | np.ndarray, truth_disparity_px: np.ndarray,
                           truth_depth_m: np.ndarray, truth_valid: np.ndarray | None = None,
                           f_px: float | None = None, baseline_m: float | None = None,
                           bad_threshold_px: float = BAD_PIXEL_PX) -> AccuracyReport:
    """Compare a frame cloud, or a disparity map (px, NaN invalid, needs ``f_px``/``baseline_m``),
    with truth maps on the same (rectified left) pixel grid."""
    if isinstance(estimate, FrameCloud):
        disparity, valid = estimate.disparity, estimate.valid
        depth = np.zeros(valid.shape, np.float64)
        depth[valid] = estimate.points[:, 2]
    else:
        if f_px is None or baseline_m is None:
            raise ReconError("evaluating a bare disparity map needs f_px and baseline_m")
        disparity = np.asarray(estimate, np.float64)
        valid = np.isfinite(disparity) & (disparity > 0)
        depth = np.zeros(valid.shape, np.float64)
        depth[valid] = f_px * baseline_m / disparity[valid]
    if disparity.shape != truth_disparity_px.shape:
        raise ReconError(f"estimate is {disparity.shape} but the truth is "
                         f"{truth_disparity_px.shape}; evaluate on the same pixel grid")
    covered = truth_depth_m > 0 if truth_valid is None else truth_valid & (truth_depth_m > 0)
    both = valid & covered
    n = int(both.sum())
    if n == 0:
        return AccuracyReport(0.0, 0, float("nan"), float("nan"), float("nan"))
    depth_error = np.abs(depth[both] - truth_depth_m[both])
    disparity_error = np.abs(disparity[both] - truth_disparity_px[both])
    return AccuracyReport(
        valid_fraction=n / max(int(covered.sum()), 1), n_valid=n,
        median_abs_depth_error_m=float(np.median(depth_error)),
        p95_abs_depth_error_m=float(np.percentile(depth_error, 95)),
        bad_pixel_rate=float(np.mean(disparity_error > bad_threshold_px)))


def calibration_from_rig(rig: object) -> object:
    """The exact calibration of a simulated :class:`~vbfe.drivers.sim.rig.StereoRig`.

    Rectification comes from ``cv2.stereoRectify`` on the true intrinsics and pose (zero
    disparity at infinity, no cropping), so a distortion-free parallel rig rectifies to itself
    and its rendered truth maps share the rectified pixel grid.
    """
    from vbfe.calib.calibration import Calibration

    size = (rig.left.width, rig.left.height)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        rig.left.K, rig.left.dist, rig.right.K, rig.right.dist, size, np.asarray(rig.R, np.float64),
        np.asarray(rig.T, np.float64).reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    return Calibration(K1=rig.left.K, D1=rig.left.dist, K2=rig.right.K, D2=rig.right.dist,
                       R=rig.R, T=rig.T, R1=R1, R2=R2, P1=P1, P2=P2, Q=Q, image_size=size,
                       K_proj=rig.projector.K, D_proj=rig.projector.dist, R_proj=rig.R_proj,
                       T_proj=rig.T_proj,
                       projector_size=(rig.projector.width, rig.projector.height),
                       info={"source": "simulated bench truth"})
