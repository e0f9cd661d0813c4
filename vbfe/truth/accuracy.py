"""Accuracy of a reconstruction against the ground truth the simulated bench renders."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from vbfe.calib import Calibration
from vbfe.common.errors import ReconError
from vbfe.recon import FrameCloud

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


def evaluate_against_truth(
    estimate: FrameCloud | np.ndarray,
    truth_disparity_px: np.ndarray,
    truth_depth_m: np.ndarray,
    truth_valid: np.ndarray | None = None,
    f_px: float | None = None,
    baseline_m: float | None = None,
    bad_threshold_px: float = BAD_PIXEL_PX,
) -> AccuracyReport:
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
        raise ReconError(
            f"estimate is {disparity.shape} but the truth is "
            f"{truth_disparity_px.shape}; evaluate on the same pixel grid"
        )
    covered = truth_depth_m > 0 if truth_valid is None else truth_valid & (truth_depth_m > 0)
    both = valid & covered
    n = int(both.sum())
    if n == 0:
        return AccuracyReport(0.0, 0, float("nan"), float("nan"), float("nan"))
    depth_error = np.abs(depth[both] - truth_depth_m[both])
    disparity_error = np.abs(disparity[both] - truth_disparity_px[both])
    return AccuracyReport(
        valid_fraction=n / max(int(covered.sum()), 1),
        n_valid=n,
        median_abs_depth_error_m=float(np.median(depth_error)),
        p95_abs_depth_error_m=float(np.percentile(depth_error, 95)),
        bad_pixel_rate=float(np.mean(disparity_error > bad_threshold_px)),
    )


def rectified_truth(
    calibration: Calibration, depth_left_m: np.ndarray, valid_left: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Truth disparity (px), depth (m) and validity of the raw left view, moved onto the
    rectified left pixel grid the reconstruction reports in (the argument order of
    :func:`evaluate_against_truth`).

    A rectified pixel's ray ``r = ((u-cx)/f, (v-cy)/f, 1)`` is ``R1ᵀ r`` in the raw camera
    frame and meets the raw image where the rectification map points; with the raw depth
    ``z`` sampled there, the rectified depth is ``z / (R1ᵀ r)_z``.
    """
    (map_x, map_y), _ = calibration.rectification_maps()
    height, width = depth_left_m.shape
    valid = np.ones(depth_left_m.shape, bool) if valid_left is None else valid_left
    depth = np.where(valid, depth_left_m, 0).astype(np.float32)
    raw_depth = cv2.remap(depth, map_x, map_y, cv2.INTER_NEAREST, borderValue=0)
    v, u = np.mgrid[0:height, 0:width]
    f, cx, cy = calibration.f, calibration.cx, calibration.cy
    ray_z = (
        calibration.R1.T @ np.stack([(u.ravel() - cx) / f, (v.ravel() - cy) / f, np.ones(u.size)])
    )[2].reshape(height, width)
    depth_rect = raw_depth / ray_z
    valid_rect = raw_depth > 0
    depth = np.where(valid_rect, depth_rect, 1.0)
    disparity = np.where(
        valid_rect, calibration.f * calibration.B / depth + calibration.disparity_offset, 0
    )
    return (
        disparity.astype(np.float32),
        np.where(valid_rect, depth_rect, 0).astype(np.float32),
        valid_rect,
    )
