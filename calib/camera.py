"""One camera's robust calibration: whole outlier views dropped first (robust z-score of the
per-view RMS), then single outlier corners (beyond both ``outlier_sigma`` robust σ and an
absolute floor), with the intrinsics' standard deviations to say how well they are determined."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.calib.board import BoardSpec, Detection
from vbfe.calib.camera_model import CameraModel
from vbfe.calib.options import CalibOptions, calib_field
from vbfe.common.errors import CalibrationError

CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)
_MIN_SIGMA_PX = 0.1  # floor of the robust residual spread: sub-pixel corner noise of real boards
_MIN_VIEW_SPREAD = 0.1  # floor of the per-view RMS spread, as a fraction of the median RMS


@dataclass
class CameraOptions(CalibOptions):
    """Knobs of the robust single-camera solve (defaults: the ``[calib]`` table)."""

    min_corners: int = calib_field("min_corners")
    min_views: int = calib_field("min_views")
    outlier_sigma: float = calib_field("outlier_sigma")
    outlier_min_px: float = calib_field("outlier_min_px")
    view_outlier_z: float = calib_field("view_outlier_z")
    view_outlier_min_px: float = calib_field("view_outlier_min_px")
    well_determined_views: int = calib_field("well_determined_views")
    fix_k3: bool = calib_field("fix_k3")  # solve k1, k2, p1, p2 only (Kalibr's radtan model)


@dataclass
class RejectedCorner:
    """A corner dropped as an outlier: view, camera, corner id, residual (px)."""

    view: str
    camera: str
    corner_id: int
    residual_px: float


@dataclass
class CameraFit:
    """One camera's calibration over the kept corners."""

    K: np.ndarray
    D: np.ndarray
    rms_px: float
    std_intrinsics: np.ndarray  # fx, fy, cx, cy, k1, k2, p1, p2, k3
    per_view_rms_px: np.ndarray
    rvecs: list[np.ndarray]
    tvecs: list[np.ndarray]
    detections: list[Detection]  # after outlier removal
    rejected: list[RejectedCorner]


def points(spec_points: np.ndarray, dets: list[Detection]) -> tuple[list, list]:
    """Object and image points (OpenCV's float32 n×1×3 / n×1×2 per view) of detections."""
    obj = [spec_points[d.ids].astype(np.float32).reshape(-1, 1, 3) for d in dets]
    img = [d.corners.astype(np.float32).reshape(-1, 1, 2) for d in dets]
    return obj, img


def residuals(
    obj: np.ndarray,
    img: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    K: np.ndarray,
    D: np.ndarray,
) -> np.ndarray:
    """Projected minus detected pixel positions (n×2) of one view's corners."""
    proj, _ = cv2.projectPoints(obj.reshape(-1, 1, 3).astype(np.float64), rvec, tvec, K, D)
    return proj.reshape(-1, 2) - img.reshape(-1, 2)


def robust_sigma(res: np.ndarray) -> float:
    """Per-axis residual spread (1.4826 × median absolute residual component), floored."""
    if res.size == 0:
        return _MIN_SIGMA_PX
    return max(1.4826 * float(np.median(np.abs(res))), _MIN_SIGMA_PX)


def _solve(
    obj: list,
    img: list,
    image_size: tuple[int, int],
    camera: str,
    fixed: CameraModel | None,
    flags: int = 0,
):
    """rms, K, D, rvecs, tvecs, std (9), per-view RMS; with ``fixed`` intrinsics only the
    board poses are solved (``solvePnP``)."""
    if fixed is not None:
        rvecs, tvecs, per_view, sq = [], [], [], []
        for o, i in zip(obj, img, strict=False):
            ok, rvec, tvec = cv2.solvePnP(o, i, fixed.K, fixed.D)
            if not ok:
                raise CalibrationError(
                    f"{camera} camera: a view's board pose cannot be solved "
                    "with the given intrinsics; are they for this camera?"
                )
            r = residuals(o, i, rvec, tvec, fixed.K, fixed.D)
            rvecs.append(rvec)
            tvecs.append(tvec)
            per_view.append(np.sqrt(np.mean(np.sum(r**2, axis=1))))
            sq.append(np.sum(r**2, axis=1))
        rms = float(np.sqrt(np.mean(np.concatenate(sq))))
        return rms, fixed.K, fixed.D, rvecs, tvecs, fixed.std_intrinsics, np.asarray(per_view)
    try:
        # OpenCV takes None for K and D (no initial guess); its stubs do not say so
        (rms, K, D, rvecs, tvecs, std, _, per_view) = cv2.calibrateCameraExtended(  # type: ignore[call-overload]
            obj, img, image_size, None, None, flags=flags, criteria=CRITERIA
        )
    except cv2.error as exc:
        raise CalibrationError(
            f"{camera} camera calibration failed in OpenCV "
            f"({str(exc).strip().splitlines()[-1]}); capture more varied "
            "views (tilted, at several distances)"
        ) from None
    return (float(rms), K, D.reshape(-1), rvecs, tvecs, std.reshape(-1)[:9], per_view.reshape(-1))


def outlier_views(
    spec: BoardSpec,
    detections: list[Detection],
    names: list[str],
    image_size: tuple[int, int],
    camera: str,
    options: CameraOptions,
    fixed: CameraModel | None = None,
) -> tuple[dict[str, str], CameraFit]:
    """Views whose per-view RMS is an outlier, with the reason (name → why), and the fit over
    all views (the final fit when none is an outlier).

    The per-view RMS is that of a solve with outlier corners removed, so single wild corners
    neither flag their view nor bias the others; a view is an outlier when its robust z-score
    ((RMS − median) / (1.4826 MAD), the spread floored at 10 % of the median) exceeds
    ``view_outlier_z`` and its RMS exceeds the median by more than ``view_outlier_min_px``
    (views at different distances differ by a few hundredths of a pixel without being bad).
    """
    fit = calibrate_camera(
        spec,
        detections,
        names,
        image_size,
        camera,
        options.outlier_sigma,
        options.outlier_min_px,
        fixed=fixed,
        flags=solve_flags(options),
    )
    rms = fit.per_view_rms_px
    median = float(np.median(rms))
    spread = max(1.4826 * float(np.median(np.abs(rms - median))), _MIN_VIEW_SPREAD * median)
    z = (rms - median) / spread
    bad = np.flatnonzero(
        (z > options.view_outlier_z) & (rms - median > options.view_outlier_min_px)
    )
    return {
        names[v]: (
            f"{camera} per-view RMS {rms[v]:.3f} px is an outlier (robust z "
            f"{z[v]:.1f} > {options.view_outlier_z:g}; median view {median:.3f} px)"
        )
        for v in bad
    }, fit


def calibrate_camera(
    spec: BoardSpec,
    detections: list[Detection],
    names: list[str],
    image_size: tuple[int, int],
    camera: str,
    outlier_sigma: float = 4.0,
    outlier_min_px: float = 1.0,
    max_rounds: int = 5,
    fixed: CameraModel | None = None,
    flags: int = 0,
) -> CameraFit:
    """Calibrate one camera, dropping corners whose residual exceeds both ``outlier_sigma`` σ
    (the robust spread of the first solve) and ``outlier_min_px``, re-solving until none is
    left. With ``fixed`` intrinsics only the board poses are solved; ``flags`` go to
    ``calibrateCameraExtended``."""
    object_points = spec.object_points()
    dets = list(detections)
    rejected: list[RejectedCorner] = []
    limit = None
    for _ in range(max_rounds):
        obj, img = points(object_points, dets)
        rms, K, D, rvecs, tvecs, std, per_view = _solve(obj, img, image_size, camera, fixed, flags)
        res = [
            residuals(o, i, r, t, K, D) for o, i, r, t in zip(obj, img, rvecs, tvecs, strict=False)
        ]
        if limit is None:
            limit = max(outlier_sigma * robust_sigma(np.concatenate(res)), outlier_min_px)
        changed = False
        for v, (det, r) in enumerate(zip(dets, res, strict=False)):
            err = np.linalg.norm(r, axis=1)
            bad = err > limit
            if bad.any():
                changed = True
                rejected += [
                    RejectedCorner(names[v], camera, int(i), float(e))
                    for i, e in zip(det.ids[bad], err[bad], strict=False)
                ]
                dets[v] = Detection(det.ids[~bad], det.corners[~bad])
        if not changed:
            break
    return CameraFit(
        K=np.asarray(K, np.float64),
        D=np.asarray(D, np.float64).reshape(-1),
        rms_px=float(rms),
        std_intrinsics=np.asarray(std, np.float64).reshape(-1),
        per_view_rms_px=np.asarray(per_view).reshape(-1),
        rvecs=list(rvecs),
        tvecs=list(tvecs),
        detections=dets,
        rejected=rejected,
    )


def solve_flags(options: CameraOptions) -> int:
    """OpenCV calibration flags the options ask for."""
    return cv2.CALIB_FIX_K3 if options.fix_k3 else 0


def uncertainty_text(K: np.ndarray, std: np.ndarray) -> str:
    """σ of f and of the principal point in px and in % of the value, one line."""
    f = (K[0, 0] + K[1, 1]) / 2
    sigma_f = float(np.hypot(std[0], std[1]) / 2)
    return (
        f"σ(f) {sigma_f:.2f} px ({100 * sigma_f / f:.2f} %), "
        f"σ(cx) {std[2]:.2f} px ({100 * std[2] / K[0, 2]:.2f} %), "
        f"σ(cy) {std[3]:.2f} px ({100 * std[3] / K[1, 2]:.2f} %)"
    )


def weak_note(n_views: int, options: CameraOptions) -> str | None:
    """A warning when too few views were solved for the intrinsics to be well determined."""
    if n_views >= options.well_determined_views:
        return None
    return (
        f"weakly determined: only {n_views} views (at least "
        f"{options.well_determined_views} recommended); trust the intrinsics only within "
        "the σ above"
    )


def need_views(n: int, options: CameraOptions, source: str, dropped: dict[str, str]) -> None:
    """Raise unless ``n`` views are enough, naming the views dropped so far and why."""
    if n < options.min_views:
        detail = "; ".join(f"{k}: {why}" for k, why in dropped.items())
        raise CalibrationError(
            f"{source}: only {n} usable views, need at least "
            f"{options.min_views} (--min-views); capture more views, or "
            "lower --min-views when the views are good and varied"
            + (f" (dropped {detail})" if detail else "")
        )
