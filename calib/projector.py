"""Projector calibration as an inverse camera (Moreno & Taubin, 3DIMPVT 2012).

For each pose of a planar ChArUco board the left camera records the board under full white,
black and OpenCV's Gray-code sequence (``cv2.structured_light.GrayCodePattern``). Around each
board corner the decoded camera→projector correspondences give a local homography, which maps
the sub-pixel camera corner to the projector. The board corners seen "by the projector" then
calibrate it like a camera, and a stereo calibration against the (already calibrated) left
camera gives its pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from vbfe.acquire.image_size import size_mismatch
from vbfe.calib.board import BoardDetector, BoardSpec
from vbfe.calib.calibration import Calibration
from vbfe.calib.options import CalibOptions, calib_field
from vbfe.common.errors import CalibrationError

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)
# Radial distortion k1, k2 only: a projector lens has little tangential distortion, and the few
# board poses a projector calibration gets cannot separate it from the principal point.
_PROJECTOR_FLAGS = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST


@dataclass
class GrayCodeCapture:
    """Left-camera images of one board pose: projector white, black, then the Gray-code
    sequence in ``GrayCodePattern.generate()`` order (grey or BGR ``uint8``)."""

    white: np.ndarray
    black: np.ndarray
    patterns: list[np.ndarray]


def _grey(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def gray_code(projector_size: tuple[int, int]) -> cv2.structured_light.GrayCodePattern:
    """OpenCV's Gray-code pattern object for a projector of ``(width, height)`` pixels."""
    return cv2.structured_light.GrayCodePattern.create(
        int(projector_size[0]), int(projector_size[1])
    )


def projector_images(
    projector_size: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """What the projector shows for one pose: white, black and the Gray-code patterns (grey)."""
    _, patterns = gray_code(projector_size).generate()
    w, h = projector_size
    return np.full((h, w), 255, np.uint8), np.zeros((h, w), np.uint8), list(patterns)


@dataclass
class ProjectorOptions(CalibOptions):
    """Knobs of :func:`calibrate_projector` (defaults: the ``[calib]`` table)."""

    window_px: int = calib_field("projector_window_px")  # half window around each corner
    min_contrast: float = calib_field("projector_min_contrast")  # white − black grey levels
    min_corners: int = calib_field("min_corners")
    min_poses: int = 4
    ransac_px: float = 2.5  # projector pixels


def corner_projector_points(
    capture: GrayCodeCapture,
    corners: np.ndarray,
    projector_size: tuple[int, int],
    options: ProjectorOptions,
) -> tuple[np.ndarray, np.ndarray]:
    """Projector pixel of each camera corner (n×2) via local homographies, and which corners
    had enough decoded pixels around them (n, bool)."""
    pattern = gray_code(projector_size)
    pattern.setWhiteThreshold(0)  # fine stripes below camera resolution decode as noise, not holes
    images = [_grey(p) for p in capture.patterns]
    expected = pattern.getNumberOfPatternImages()
    if len(images) != expected:
        raise CalibrationError(
            f"a {projector_size[0]}x{projector_size[1]} projector needs "
            f"{expected} Gray-code images per pose, got {len(images)}"
        )
    lit = _grey(capture.white).astype(np.int16) - _grey(capture.black).astype(np.int16)
    h, w = lit.shape
    r = options.window_px
    out = np.zeros((len(corners), 2))
    ok = np.zeros(len(corners), bool)
    for k, (cx, cy) in enumerate(corners):
        x0, x1 = max(int(round(cx)) - r, 0), min(int(round(cx)) + r, w - 1)
        y0, y1 = max(int(round(cy)) - r, 0), min(int(round(cy)) + r, h - 1)
        cam, proj = [], []
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                if lit[y, x] < options.min_contrast:
                    continue
                err, pix = pattern.getProjPixel(images, x, y)
                if not err:
                    cam.append((x, y))
                    proj.append(pix)
        if len(cam) < (r + 1) ** 2:  # need a good part of the window
            continue
        H, inliers = cv2.findHomography(
            np.asarray(cam, np.float64), np.asarray(proj, np.float64), cv2.RANSAC, options.ransac_px
        )
        if H is None or inliers.sum() < 0.5 * len(cam):
            continue
        out[k] = cv2.perspectiveTransform(np.array([[[cx, cy]]], np.float64), H).reshape(2)
        ok[k] = True
    return out, ok


@dataclass
class ProjectorResult:
    """Projector intrinsics and pose, plus per-pose diagnostics."""

    K: np.ndarray
    D: np.ndarray
    R: np.ndarray  # left camera → projector
    T: np.ndarray
    rms_px: float
    rms_stereo_px: float
    per_pose_rms_px: np.ndarray
    corners_used: list[int] = field(default_factory=list)


def calibrate_projector(
    captures: list[GrayCodeCapture],
    spec: BoardSpec,
    camera: Calibration,
    projector_size: tuple[int, int],
    options: ProjectorOptions | None = None,
) -> ProjectorResult:
    """Calibrate the projector from Gray-code captures of the board at several poses, and its
    pose relative to the left camera of ``camera``."""
    options = options or ProjectorOptions()
    detector = BoardDetector(spec)
    board_points = spec.object_points()
    obj, cam_pts, proj_pts, used = [], [], [], []
    for i, capture in enumerate(captures):
        mismatch = size_mismatch(
            f"pose {i} has", capture.white.shape[1::-1], "the camera calibration", camera.image_size
        )
        if mismatch:
            raise CalibrationError(mismatch)
        det = detector.detect(capture.white)
        if len(det) < options.min_corners:
            continue
        proj, ok = corner_projector_points(capture, det.corners, projector_size, options)
        if ok.sum() < options.min_corners:
            continue
        obj.append(board_points[det.ids[ok]].astype(np.float32).reshape(-1, 1, 3))
        cam_pts.append(det.corners[ok].astype(np.float32).reshape(-1, 1, 2))
        proj_pts.append(proj[ok].astype(np.float32).reshape(-1, 1, 2))
        used.append(int(ok.sum()))
    if len(obj) < options.min_poses:
        raise CalibrationError(
            f"only {len(obj)} of {len(captures)} poses show at least "
            f"{options.min_corners} board corners lit by the projector; need "
            f"{options.min_poses}. Keep the board inside the projected area"
        )
    try:
        # OpenCV takes None for K and D (no initial guess); its stubs do not say so
        rms, K, D, _, _, _, _, per_pose = cv2.calibrateCameraExtended(  # type: ignore[call-overload]
            obj, proj_pts, projector_size, None, None, flags=_PROJECTOR_FLAGS, criteria=_CRITERIA
        )
        rms_st, *_, R, T, _, _ = cv2.stereoCalibrate(
            obj,
            cam_pts,
            proj_pts,
            camera.K1,
            camera.D1,
            K,
            D,
            camera.image_size,
            flags=cv2.CALIB_FIX_INTRINSIC,
            criteria=_CRITERIA,
        )
    except cv2.error as exc:
        raise CalibrationError(
            f"projector calibration failed in OpenCV "
            f"({str(exc).strip().splitlines()[-1]}); use more varied poses"
        ) from None
    return ProjectorResult(
        K=K,
        D=D.reshape(-1),
        R=R,
        T=T.reshape(3),
        rms_px=float(rms),
        rms_stereo_px=float(rms_st),
        per_pose_rms_px=per_pose.reshape(-1),
        corners_used=used,
    )


def with_projector(
    calibration: Calibration, result: ProjectorResult, projector_size: tuple[int, int]
) -> Calibration:
    """``calibration`` with the projector's intrinsics and pose added."""
    info = dict(calibration.info)
    info["projector"] = {
        "rms_stereo_px": result.rms_stereo_px,
        "per_pose_rms_px": [float(v) for v in result.per_pose_rms_px],
        "corners_per_pose": result.corners_used,
    }
    return calibration.replace(
        K_proj=result.K,
        D_proj=result.D,
        R_proj=result.R,
        T_proj=result.T,
        projector_size=projector_size,
        rms_projector_px=result.rms_px,
        info=info,
    )


def save_captures(folder: str | Path, captures: list[GrayCodeCapture], start: int = 0) -> None:
    """Write ``pose_NNN/white.png``, ``black.png``, ``gray_NN.png`` for every pose (numbered
    from ``start``)."""
    for i, capture in enumerate(captures, start=start):
        pose = Path(folder) / f"pose_{i:03d}"
        pose.mkdir(parents=True, exist_ok=True)
        images = {
            "white": capture.white,
            "black": capture.black,
            **{f"gray_{k:02d}": p for k, p in enumerate(capture.patterns)},
        }
        for name, image in images.items():
            if not cv2.imwrite(str(pose / f"{name}.png"), image):
                raise CalibrationError(f"cannot write {pose / name}.png")


def _read_gray(pose: Path, name: str) -> np.ndarray:
    image = cv2.imread(str(pose / f"{name}.png"), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise CalibrationError(f"missing or unreadable {pose / name}.png")
    return image


def load_captures(folder: str | Path) -> list[GrayCodeCapture]:
    """Read what :func:`save_captures` wrote."""
    folder = Path(folder)
    poses = sorted(p for p in folder.glob("pose_*") if p.is_dir())
    if not poses:
        raise CalibrationError(f"{folder} holds no pose_NNN folders of Gray-code images")
    out = []
    for pose in poses:
        grays = sorted(p.stem for p in pose.glob("gray_*.png"))
        white, black = _read_gray(pose, "white"), _read_gray(pose, "black")
        out.append(GrayCodeCapture(white, black, [_read_gray(pose, g) for g in grays]))
    return out
