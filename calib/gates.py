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
from vbfe.calib.options import calib_field, from_table

_GRID_STEP = 8  # px between sampled pixels when measuring rectification coverage


@dataclass
class GateLimits:
    """Limits of the sanity gates (defaults: the ``[calib]`` table)."""

    min_baseline_m: float = calib_field("min_baseline_mm", 1e-3)
    nominal_baseline_m: float = calib_field("nominal_baseline_mm", 1e-3)  # 0: not checked
    baseline_tolerance: float = calib_field("baseline_tolerance")  # of the nominal baseline
    max_rms_px: float = calib_field("max_rms_px")
    min_rectified_fraction: float = calib_field("min_rectified_fraction")

    @classmethod
    def from_config(cls, calib_table: dict) -> GateLimits:
        """Limits from a rig config's ``[calib]`` table (baselines there in mm)."""
        return from_table(cls, calib_table)


def _grid(size: tuple[int, int]) -> np.ndarray:
    u, v = np.meshgrid(
        np.arange(0, size[0], _GRID_STEP, dtype=np.float64),
        np.arange(0, size[1], _GRID_STEP, dtype=np.float64),
    )
    return np.column_stack([u.ravel(), v.ravel()])


def _inside(uv: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    return (
        np.isfinite(uv).all(axis=1)
        & (uv[:, 0] >= 0)
        & (uv[:, 0] <= size[0] - 1)
        & (uv[:, 1] >= 0)
        & (uv[:, 1] <= size[1] - 1)
    )


def rectified_fractions(
    K: np.ndarray, D: np.ndarray, R: np.ndarray, P: np.ndarray, size: tuple[int, int]
) -> tuple[float, float]:
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


def stereo_problems(
    cal: Calibration, limits: GateLimits, view_names: list[str] | None = None
) -> list[str]:
    """Why ``cal`` is not a usable stereo calibration (empty when it passes every gate), each
    with the quantity, its value and limit, and a remedy; ``view_names`` (of the rows of
    ``cal.per_view_rms_px``) let a high RMS name its worst views."""
    problems = []
    B, T = cal.B, float(np.linalg.norm(cal.T))
    if not np.isfinite(B) or not np.isfinite(T):
        problems.append("baseline is not a finite number")
    elif min(abs(B), T) < limits.min_baseline_m:
        problems.append(
            f"baseline {abs(min(B, T, key=abs)) * 1e3:.4f} mm is below the minimum "
            f"{limits.min_baseline_m * 1e3:g} mm ([calib] min_baseline_mm): the left "
            "and right images look like one camera's; check the eyes are two "
            "cameras, and that --square-mm is the board's square in mm"
        )
    elif B < 0:
        problems.append(
            f"baseline {B * 1e3:.4f} mm is negative (limit: above 0): the left and "
            "right images look swapped; exchange the eyes' files"
        )
    elif (
        limits.nominal_baseline_m > 0
        and abs(B / limits.nominal_baseline_m - 1) > limits.baseline_tolerance
    ):
        problems.append(
            f"baseline {B * 1e3:.4f} mm is more than "
            f"{limits.baseline_tolerance * 100:g} % from the rig's nominal "
            f"{limits.nominal_baseline_m * 1e3:g} mm; set the rig's baseline as "
            "[calib] nominal_baseline_mm or --nominal-baseline-mm (0 = not checked)"
        )
    w, h = cal.image_size
    for eye, P in (("left", cal.P1), ("right", cal.P2)):
        cx, cy = P[0, 2], P[1, 2]
        if not (np.isfinite(cx) and np.isfinite(cy) and 0 <= cx < w and 0 <= cy < h):
            problems.append(
                f"rectified {eye} principal point ({cx:.1f}, {cy:.1f}) px lies "
                f"outside the {w}x{h} image: the views do not pin the cameras down; "
                "add views that fill the image corners, tilted by 20-40°"
            )
    for eye, K, D, R, P in (
        ("left", cal.K1, cal.D1, cal.R1, cal.P1),
        ("right", cal.K2, cal.D2, cal.R2, cal.P2),
    ):
        valid, kept = rectified_fractions(K, D, R, P, cal.image_size)
        if min(valid, kept) < limits.min_rectified_fraction:
            problems.append(
                f"rectified {eye} image shows {valid * 100:.0f} % valid pixels and "
                f"keeps {kept * 100:.0f} % of the camera image (limit "
                f"{limits.min_rectified_fraction * 100:g} %, [calib] "
                "min_rectified_fraction): the eyes look far apart in angle or the "
                "distortion is poorly determined; add views near the image edges"
            )
    rms = max(
        (v for v in (cal.rms_left_px, cal.rms_right_px, cal.rms_stereo_px) if np.isfinite(v)),
        default=float("nan"),
    )
    if np.isfinite(rms) and rms > limits.max_rms_px:
        problems.append(
            f"RMS reprojection error {rms:.3f} px (left {cal.rms_left_px:.3f}, right "
            f"{cal.rms_right_px:.3f}, stereo {cal.rms_stereo_px:.3f}) is above the "
            f"limit {limits.max_rms_px:g} px (--max-rms-px)" + _rms_remedy(cal, view_names)
        )
    return problems


def _rms_remedy(cal: Calibration, view_names: list[str] | None) -> str:
    """Why the RMS is high, as far as the per-view RMS tells: a few bad views (named) or all."""
    per_view = cal.per_view_rms_px
    if per_view is None or view_names is None or len(view_names) != len(per_view):
        return ": check the board options match the printed board"
    worst = per_view.max(axis=1)
    median = float(np.median(worst))
    bad = [
        f"{view_names[i]} ({worst[i]:.2f} px)"
        for i in np.argsort(worst)[::-1]
        if worst[i] > 2 * median
    ][:5]
    if bad:
        return (
            f": a few views fit much worse than the median view ({median:.2f} px): "
            f"{', '.join(bad)}; retake or remove them"
        )
    return (
        f": every view fits about as badly (median {median:.2f} px): check the board options "
        "(--inner-corners/--squares-x/-y) match the printed board, or for a coarse camera "
        "raise --max-rms-px"
    )


def camera_problems(
    K: np.ndarray, size: tuple[int, int], rms_px: float, limits: GateLimits
) -> list[str]:
    """Why a single-camera calibration is unusable (empty when it passes)."""
    problems = []
    w, h = size
    if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0):
        problems.append(f"focal length ({K[0, 0]:.1f}, {K[1, 1]:.1f}) px is not positive")
    if not (0 <= K[0, 2] < w and 0 <= K[1, 2] < h):
        problems.append(
            f"principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) px lies outside the {w}x{h} image"
        )
    if not np.isfinite(rms_px) or rms_px > limits.max_rms_px:
        problems.append(
            f"RMS reprojection error {rms_px:.3f} px is above the limit "
            f"{limits.max_rms_px:g} px (--max-rms-px): check the board options "
            "match the printed board, or for a coarse camera raise --max-rms-px"
        )
    return problems
