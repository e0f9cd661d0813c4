"""Plain OpenCV chessboard calibration pipelines: the reference vbfe's corners are measured
against (issue 40). Each pipeline detects the board as OpenCV's samples do, calibrates each camera
with ``calibrateCamera`` and the pair with ``stereoCalibrate`` from those intrinsics, and takes no
vbfe code: corners of one eye are renumbered to match the other only by which numbering moves
all corners by nearly one shift (what any stereo user has to do)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

# cornerSubPix half-sizes (OpenCV's winSize: (5, 5) is an 11×11 window) and the sector detector
PIPELINES = ("subpix5", "subpix8", "subpix11", "sb_accuracy")
_SUBPIX = (cv2.TERM_CRITERIA_MAX_ITER + cv2.TERM_CRITERIA_EPS, 30, 0.01)  # stereo_calib.cpp
_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9)


def grey_of(image: np.ndarray) -> np.ndarray:
    """The image in grey levels."""
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def corners(image: np.ndarray, inner: tuple[int, int], pipeline: str) -> np.ndarray | None:
    """The board's inner corners (n×2, float32) by one pipeline; ``None`` when not found."""
    grey = grey_of(image)
    if pipeline == "sb_accuracy":
        found, found_corners = cv2.findChessboardCornersSB(grey, inner, flags=cv2.CALIB_CB_ACCURACY)
        return found_corners.reshape(-1, 2) if found else None
    half = int(pipeline.removeprefix("subpix"))
    found, found_corners = cv2.findChessboardCorners(
        grey, inner, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    if not found:
        return None
    refined = cv2.cornerSubPix(grey, found_corners, (half, half), (-1, -1), _SUBPIX)
    return refined.reshape(-1, 2)


def object_points(inner: tuple[int, int], square_m: float) -> np.ndarray:
    """Board corners (n×3, float32), row-major as OpenCV numbers them."""
    nx, ny = inner
    grid = np.zeros((nx * ny, 3), np.float32)
    grid[:, :2] = np.mgrid[0:nx, 0:ny].T.reshape(-1, 2) * square_m
    return grid


def _as_left(left: np.ndarray, right: np.ndarray, inner: tuple[int, int]) -> np.ndarray:
    nx, ny = inner
    grid = right.reshape(ny, nx, 2)
    turns = (0, 1, 2, 3) if nx == ny else (0, 2)
    options = [np.rot90(grid, k).reshape(-1, 2) for k in turns]
    spread = [np.std(o - left, axis=0).sum() for o in options]
    return options[int(np.argmin(spread))]


@dataclass
class PlainStereo:
    """One pipeline's stereo calibration: per-eye RMS, joint RMS, |T| (m), pairs used."""

    rms_left: float
    rms_right: float
    rms: float
    T_norm: float
    K1: np.ndarray
    K2: np.ndarray
    n_pairs: int


def stereo(
    pairs: Sequence[tuple[np.ndarray, np.ndarray]],
    inner: tuple[int, int],
    square_m: float,
    pipeline: str,
) -> PlainStereo:
    """Each eye's ``calibrateCamera``, then ``stereoCalibrate`` from them (intrinsics refined),
    on the pairs where the pipeline finds the board in both eyes."""
    left, right = [], []
    for image_left, image_right in pairs:
        cl, cr = corners(image_left, inner, pipeline), corners(image_right, inner, pipeline)
        if cl is not None and cr is not None:
            left.append(cl)
            right.append(_as_left(cl, cr, inner))
    size = grey_of(pairs[0][0]).shape[::-1]
    obj = [object_points(inner, square_m)] * len(left)
    rms_l, K1, D1, _, _ = cv2.calibrateCamera(obj, left, size, None, None, criteria=_CRITERIA)
    rms_r, K2, D2, _, _ = cv2.calibrateCamera(obj, right, size, None, None, criteria=_CRITERIA)
    rms, K1, _, K2, _, _, T, _, _ = cv2.stereoCalibrate(
        obj,
        left,
        right,
        K1,
        D1,
        K2,
        D2,
        size,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS,
        criteria=_CRITERIA,
    )
    return PlainStereo(
        float(rms_l), float(rms_r), float(rms), float(np.linalg.norm(T)), K1, K2, len(left)
    )


def all_stereo(
    pairs: Sequence[tuple[np.ndarray, np.ndarray]], inner: tuple[int, int], square_m: float
) -> dict[str, PlainStereo]:
    """Every pipeline's stereo calibration of the pairs."""
    return {p: stereo(pairs, inner, square_m, p) for p in PIPELINES}


def best(results: dict[str, PlainStereo], key: str = "rms") -> tuple[str, PlainStereo]:
    """The pipeline with the lowest ``key`` (``rms``, ``rms_left``, ``rms_right``) among those
    that keep the most pairs (vbfe is measured on every pair: a pipeline that drops the
    hardest views is not its peer), and its result."""
    most = max(r.n_pairs for r in results.values())
    name = min(
        (p for p, r in results.items() if r.n_pairs == most),
        key=lambda p: getattr(results[p], key),
    )
    return name, results[name]
