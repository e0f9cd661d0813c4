"""Stereo rectification of a solved pair (OpenCV's ``stereoRectify``) and how much of each
eye's image it keeps.

OpenCV's zero-disparity rectification gives both rectified eyes one principal point. When the
eyes' own principal points lie far apart (an analog endoscope's digitiser samples the two
channels' lines from different starts) that crops most of the image; rectifying without it
keeps each eye's principal point and stores their offset as ``doffs`` (d = f·B/z − doffs).

The rectified camera matrix (:data:`UNSCALED`, the default) depends on the cameras' focal
lengths and principal points only, not on the distortion at the image border (extrapolated
beyond the board views, so weaker views move it): stereoRectify's free scaling crops to where
the undistorted border lies, which moved the rectified focal length 0.1–6 % between two
calibrations whose focal lengths agree within 0.05 %.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.calib.calibration import reprojection_matrix

ZERO_DISPARITY = ("auto", "on", "off")  # auto: on unless it keeps less than the gate's fraction
UNSCALED = -1.0  # alpha: no free scaling (see stereo_rectify)
ALPHAS = (UNSCALED, *(k / 10 for k in range(11)))  # scalings tried when one fails
_GRID_STEP = 8  # px between sampled pixels when measuring rectification coverage


@dataclass
class Rectification:
    """``stereoRectify``'s rotations and projections, and whether zero disparity was forced."""

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    zero_disparity: bool
    alpha: float = 0.0  # stereoRectify's free scaling


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


def worst_fraction(
    K1: np.ndarray,
    D1: np.ndarray,
    K2: np.ndarray,
    D2: np.ndarray,
    rect: Rectification,
    size: tuple[int, int],
) -> float:
    """The smaller of valid and kept (:func:`rectified_fractions`) over both eyes."""
    return min(
        min(rectified_fractions(K1, D1, rect.R1, rect.P1, size)),
        min(rectified_fractions(K2, D2, rect.R2, rect.P2, size)),
    )


def stereo_rectify(
    K1: np.ndarray,
    D1: np.ndarray,
    K2: np.ndarray,
    D2: np.ndarray,
    size: tuple[int, int],
    R: np.ndarray,
    T: np.ndarray,
    alpha: float,
    zero_disparity: bool,
) -> Rectification:
    """``cv2.stereoRectify``'s rotations; its free scaling ``alpha`` (0–1, the new image size is
    the image size) or, for a negative ``alpha`` (:data:`UNSCALED`), no free scaling: the
    rectified focal length is the smaller of the eyes' fy (OpenCV's unscaled choice, without
    its k1 term) and each eye's principal ray lands on its own principal point (rows shared;
    with ``zero_disparity`` the columns too, at their mean)."""
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        K1,
        D1,
        K2,
        D2,
        size,
        R,
        np.asarray(T, np.float64).reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY if zero_disparity else 0,
        alpha=max(alpha, 0.0),
        newImageSize=size,
    )
    if alpha < 0:
        P1, P2 = _unscaled(K1, K2, R1, R2, P2, zero_disparity)
        Q = reprojection_matrix(P1, P2)
    return Rectification(R1, R2, P1, P2, Q, zero_disparity, alpha)


def _unscaled(
    K1: np.ndarray,
    K2: np.ndarray,
    R1: np.ndarray,
    R2: np.ndarray,
    P2: np.ndarray,
    zero_disparity: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """The rectified projections of :data:`UNSCALED` (``P2``: OpenCV's, for the baseline)."""
    f = min(K1[1, 1], K2[1, 1])
    centres = []
    for K, R in ((K1, R1), (K2, R2)):
        axis = R[:, 2]  # the eye's principal ray in the rectified frame
        centres.append(K[:2, 2] - f * axis[:2] / axis[2])
    cy = (centres[0][1] + centres[1][1]) / 2
    cx = [c[0] for c in centres]
    if zero_disparity:
        cx = [(cx[0] + cx[1]) / 2] * 2
    P = [np.array([[f, 0.0, c, 0.0], [0.0, f, cy, 0.0], [0.0, 0.0, 1.0, 0.0]]) for c in cx]
    P[1][0, 3] = f * P2[0, 3] / P2[0, 0]
    return P[0], P[1]


def usable(rect: Rectification) -> bool:
    """Whether both rectified eyes have a finite, positive focal length (``stereoRectify`` gives
    a negative one for free scaling of some geometries)."""
    return bool(
        np.isfinite(rect.P1).all()
        and np.isfinite(rect.P2).all()
        and rect.P1[0, 0] > 0
        and rect.P2[0, 0] > 0
    )


def _score(K1, D1, K2, D2, rect: Rectification, size: tuple[int, int]) -> float:
    return worst_fraction(K1, D1, K2, D2, rect, size) if usable(rect) else -1.0


def rectify(
    K1: np.ndarray,
    D1: np.ndarray,
    K2: np.ndarray,
    D2: np.ndarray,
    size: tuple[int, int],
    R: np.ndarray,
    T: np.ndarray,
    alpha: float,
    zero_disparity: str,
    min_fraction: float,
) -> Rectification:
    """The pair's rectification: ``zero_disparity`` ``on``/``off`` forces or leaves out
    OpenCV's zero-disparity flag; ``auto`` forces it unless that keeps less than
    ``min_fraction`` of an eye's image and leaving it out keeps more. When neither keeps
    ``min_fraction`` at ``alpha``, the scaling in :data:`ALPHAS` that keeps most (the
    smaller of valid and kept, :func:`worst_fraction`) is taken; its alpha is ``alpha``."""
    if zero_disparity not in ZERO_DISPARITY:
        raise ValueError(f"zero_disparity must be one of {ZERO_DISPARITY}, got {zero_disparity!r}")
    forced = stereo_rectify(K1, D1, K2, D2, size, R, T, alpha, zero_disparity != "off")
    if zero_disparity != "auto" or _score(K1, D1, K2, D2, forced, size) >= min_fraction:
        best = forced
    else:
        free = stereo_rectify(K1, D1, K2, D2, size, R, T, alpha, False)
        better = _score(K1, D1, K2, D2, free, size) > _score(K1, D1, K2, D2, forced, size)
        best = free if better else forced
    if _score(K1, D1, K2, D2, best, size) >= min_fraction:
        return best
    settings = [best.zero_disparity] if zero_disparity != "auto" else [True, False]
    tried = [
        stereo_rectify(K1, D1, K2, D2, size, R, T, a, zero)
        for zero in settings
        for a in ALPHAS
        if a != alpha
    ]
    return max([best, *tried], key=lambda r: _score(K1, D1, K2, D2, r, size))
