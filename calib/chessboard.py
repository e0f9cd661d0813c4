"""Plain chessboards: corners as accurate as OpenCV's calibration samples at any resolution, and
one corner numbering for both eyes of a stereo view.

A chessboard reads the same turned by 180° (a square one also by 90°), so the detector may
number a view's left and right corners from different ends. :func:`same_numbering` takes the
right eye's numbering whose left→right displacements agree (nearly one shift for all corners,
as a stereo pair sees them).
"""

from __future__ import annotations

import cv2
import numpy as np

# cornerSubPix half-window: OpenCV's 11×11 window (half 5) at least, growing with the corner
# spacing for sharper fits on high-resolution images, and never beyond 0.35 × the spacing:
# measured on OpenCV's stereo sample (spacing 21-37 px), half-windows above ~0.4 × spacing (e.g.
# the 23×23 of stereo_calib.cpp) reach the neighbouring squares' edges and move single corners
# by 1-6 px; 0.2 × spacing keeps each view within 0.09 px of OpenCV's 11×11 corners and, on the
# images upscaled 2-3×, keeps the per-camera RMS at 0.20-0.22 px where 11×11 gives 0.30-0.70.
_MIN_HALF_WINDOW = 5
_HALF_WINDOW_PER_SPACING = 0.2
_MAX_HALF_WINDOW_PER_SPACING = 0.35
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
# the other numbering must spread the displacements this many times more to be ruled out
_MIN_NUMBERING_CONTRAST = 3.0


def corner_spacing(corners: np.ndarray, inner: tuple[int, int]) -> float:
    """Smallest distance (px) between neighbouring corners along the board's rows and columns."""
    nx, ny = inner
    grid = corners.reshape(ny, nx, 2)
    return float(
        min(
            np.linalg.norm(np.diff(grid, axis=1), axis=2).min(),
            np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
        )
    )


def half_window(spacing_px: float) -> int:
    """The cornerSubPix half-window for corners ``spacing_px`` apart (see the constants)."""
    grown = max(_MIN_HALF_WINDOW, round(_HALF_WINDOW_PER_SPACING * spacing_px))
    return int(max(2, min(grown, int(_MAX_HALF_WINDOW_PER_SPACING * spacing_px))))


def detect_chessboard(grey: np.ndarray, inner: tuple[int, int]) -> np.ndarray | None:
    """All inner corners (n×2 px, row-major, numbered from either end as OpenCV finds them) of
    a chessboard in a grey image, sub-pixel refined; ``None`` when the board is not seen whole."""
    found, corners = cv2.findChessboardCorners(
        grey, inner, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    if not found:  # the sector-based detector finds boards the classic one misses
        found, corners = cv2.findChessboardCornersSB(
            grey, inner, flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE
        )
    if not found:
        return None
    corners = corners.reshape(-1, 1, 2).astype(np.float32)
    half = half_window(corner_spacing(corners, inner))
    corners = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1), _SUBPIX_CRITERIA)
    return corners.reshape(-1, 2).astype(np.float64)


def _displacement_spread(left: np.ndarray, right: np.ndarray) -> float:
    shifts = right - left
    return float(np.median(np.linalg.norm(shifts - np.median(shifts, axis=0), axis=1)))


def _numberings(corners: np.ndarray, inner: tuple[int, int]) -> list[np.ndarray]:
    """The corners in every numbering that reads the same board: as found and turned by 180°,
    and for a square board also by ±90°."""
    nx, ny = inner
    grid = corners.reshape(ny, nx, 2)
    turns = (0, 1, 2, 3) if nx == ny else (0, 2)
    return [np.rot90(grid, k).reshape(-1, 2).copy() for k in turns]


def same_numbering(
    left: np.ndarray, right: np.ndarray, inner: tuple[int, int]
) -> tuple[np.ndarray, bool, float]:
    """The right eye's corners (n×2) numbered as the left eye's, whether they were renumbered,
    and how clearly: the runner-up numbering's displacement spread over the chosen one's
    (below :data:`_MIN_NUMBERING_CONTRAST` the view is ambiguous)."""
    candidates = _numberings(right, inner)
    spreads = [_displacement_spread(left, c) for c in candidates]
    order = np.argsort(spreads)
    best, runner_up = int(order[0]), int(order[1])
    return (candidates[best], best != 0, spreads[runner_up] / max(spreads[best], 1e-9))


def is_clear(contrast: float) -> bool:
    """Whether a numbering chosen with this contrast is trusted."""
    return contrast >= _MIN_NUMBERING_CONTRAST
