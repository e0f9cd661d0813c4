"""Sanity gates: physically impossible or unusable calibrations are refused, not written.

A stereo calibration is refused when its baseline is not finite, negative (eyes swapped),
below a minimum or far from the rig's nominal baseline, when a rectified principal point lies
outside the image, when rectification keeps less than a fraction of the image, or when its
RMS reprojection error is above a limit. ``calibrate stereo`` raises on these before writing;
``calibrate check`` says NO-GO for such a file.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.calib.options import from_table

_GRID_STEP = 8  # px between sampled pixels when measuring rectification coverage


@dataclass
class GateLimits:
    """Limits of the sanity gates (defaults match the ``[calib]`` table)."""

    min_baseline_m: float = 0.0005
    nominal_baseline_m: float = 0.0  # 0: not checked
    baseline_tolerance: float = 0.25  # fraction of the nominal baseline
    max_rms_px: float = 1.0
    min_rectified_fraction: float = 0.5

    @classmethod
    def from_config(cls, calib_table: dict) -> "GateLimits":
        """Limits from a rig config's ``[calib]`` table (baselines there in mm)."""
        return from_table(cls, calib_table,
                          keys={"min_baseline_m": "min_baseline_mm",
                                "nominal_baseline_m": "nominal_baseline_mm"},
                          scales={"min_baseline_m": 1e-3, "nominal_baseline_m": 1e-3})


def _grid(size: tuple[int, int]) -> np.ndarray:
    u, v = np.meshgrid(np.arange(0, size[0], _GRID_STEP, dtype=np.float64),
                       np.arange(0, size[1], _GRID_STEP, dtype=np.float64))
    return np.column_stack([u.ravel(), v.ravel()])


def _inside(uv: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    return (np.isfinite(uv).all(axis=1) & (uv[:, 0] >= 0) & (uv[:, 0] <= size[0] - 1)
            & (uv[:, 1] >= 0) & (uv[:, 1] <= size[1] - 1))


def rectified_fractions(K: np.ndarray, D: np.ndarray, R: np.ndarray, P: np.ndarray,
                        size: tuple[int, int]) -> tuple[float, float]:
    """(valid, kept) for one eye: the fraction of the rectified image that shows the camera
    image, and the fraction of the camera image that appears in the rectified image."""
    grid = _grid(size)
    K_rect = P[:, :3]
    if not np.all(np.isfinite(K_rect)) or abs(np.linalg.det(K_rect)) < 1e-12:
        return 0.0, 0.0
    rays = np.column_stack([grid, np.ones(len(grid))]) @ np.linalg.inv(K_rect).T @ R
    front = rays[:, 2] > 0
    valid = 0.0
    if front.any():
        raw, _ = cv2.projectPoints(rays[front].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
        valid = _inside(raw.reshape(-1, 2), size).sum() / len(grid)
    rect = cv2.undistortPoints(grid.reshape(-1, 1, 2), K, D, R=R, P=P).reshape(-1, 2)
    kept = _inside(rect, size).mean()
    return float(valid), float(kept)


def stereo_problems(cal: Calibration, limits: GateLimits) -> list[str]:
    """Why ``cal`` is not a usable stereo calibration (empty when it passes every gate)."""
    problems = []
    B, T = cal.B, float(np.linalg.norm(cal.T))
    if not np.isfinite(B) or not np.isfinite(T):
        problems.append("baseline is not a finite number")
    elif min(abs(B), T) < limits.min_baseline_m:
        problems.append(f"baseline {abs(min(B, T, key=abs)) * 1e3:.4f} mm is below the minimum "
                        f"{limits.min_baseline_m * 1e3:g} mm (min_baseline_mm): are the left "
                        "and right images from different cameras?")
    elif B < 0:
        problems.append(f"baseline {B * 1e3:.4f} mm is negative: the left and right images look "
                        "swapped")
    elif limits.nominal_baseline_m > 0 and \
            abs(B / limits.nominal_baseline_m - 1) > limits.baseline_tolerance:
        problems.append(f"baseline {B * 1e3:.4f} mm is more than "
                        f"{limits.baseline_tolerance * 100:g} % from the rig's nominal "
                        f"{limits.nominal_baseline_m * 1e3:g} mm; set the rig's baseline as "
                        "[calib] nominal_baseline_mm or --nominal-baseline-mm (0 = not checked)")
    w, h = cal.image_size
    for eye, P in (("left", cal.P1), ("right", cal.P2)):
        cx, cy = P[0, 2], P[1, 2]
        if not (np.isfinite(cx) and np.isfinite(cy) and 0 <= cx < w and 0 <= cy < h):
            problems.append(f"rectified {eye} principal point ({cx:.1f}, {cy:.1f}) px lies "
                            f"outside the {w}x{h} image")
    for eye, K, D, R, P in (("left", cal.K1, cal.D1, cal.R1, cal.P1),
                            ("right", cal.K2, cal.D2, cal.R2, cal.P2)):
        valid, kept = rectified_fractions(K, D, R, P, cal.image_size)
        if min(valid, kept) < limits.min_rectified_fraction:
            problems.append(f"rectified {eye} image shows {valid * 100:.0f} % valid pixels and "
                            f"keeps {kept * 100:.0f} % of the camera image (limit "
                            f"{limits.min_rectified_fraction * 100:g} %)")
    rms = max((v for v in (cal.rms_left_px, cal.rms_right_px, cal.rms_stereo_px)
               if np.isfinite(v)), default=float("nan"))
    if np.isfinite(rms) and rms > limits.max_rms_px:
        problems.append(f"RMS reprojection error {rms:.3f} px is above the limit "
                        f"{limits.max_rms_px:g} px (max_rms_px): check the board parameters "
                        "and drop blurred views")
    return problems


def camera_problems(K: np.ndarray, size: tuple[int, int], rms_px: float,
                    limits: GateLimits) -> list[str]:
    """Why a single-camera calibration is unusable (empty when it passes)."""
    problems = []
    w, h = size
    if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0):
        problems.append(f"focal length ({K[0, 0]:.1f}, {K[1, 1]:.1f}) px is not positive")
    if not (0 <= K[0, 2] < w and 0 <= K[1, 2] < h):
        problems.append(f"principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) px lies outside the "
                        f"{w}x{h} image")
    if not np.isfinite(rms_px) or rms_px > limits.max_rms_px:
        problems.append(f"RMS reprojection error {rms_px:.3f} px is above the limit "
                        f"{limits.max_rms_px:g} px (max_rms_px)")
    return problems
