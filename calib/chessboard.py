"""Plain chessboards: finding the board (:func:`find_chessboard`), the cornerSubPix windows
worth comparing (the crossings of the board's edge lines are :mod:`vbfe.calib.edge_lines`'),
and one corner numbering for every eye and view.

A chessboard reads the same turned by 180° (a square one also by 90°), and OpenCV may number
it from either end (a square one turned or mirrored): :func:`canonical` numbers every detection
one way, and :func:`same_numbering` takes the right eye's numbering whose left→right
displacements agree (nearly one shift for all corners, as a stereo pair sees them) where a
board seen edge-on in x leaves the two eyes' canonical numberings apart.
"""

from __future__ import annotations

import cv2
import numpy as np

# The adaptive cornerSubPix half-window (the first candidate, and the refinement of detections
# made outside calibration): OpenCV's 11×11 window (half 5) at least, growing with the corner
# spacing for sharper fits on high-resolution images, and never beyond 0.35 × the spacing:
# measured on OpenCV's stereo sample (spacing 21-37 px), half-windows above ~0.4 × spacing (e.g.
# the 23×23 of stereo_calib.cpp) reach the neighbouring squares' edges and move single corners
# by 1-6 px; 0.2 × spacing keeps each view within 0.09 px of OpenCV's 11×11 corners and, on the
# images upscaled 2-3×, keeps the per-camera RMS at 0.20-0.22 px where 11×11 gives 0.30-0.70.
_MIN_HALF_WINDOW = 5
_HALF_WINDOW_PER_SPACING = 0.2
_MAX_HALF_WINDOW_PER_SPACING = 0.35
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
# No single window suits every image (issue 40): soft, noisy corners want OpenCV's larger windows
# (half 8-11), small sharp ones the adaptive window; each view keeps the candidate that fits the
# board best (vbfe.calib.corner_choice), most often the edge-line crossings. Windows beyond
# 0.75 × the spacing take in the next row's edges wholesale and are not tried.
_TRIED_HALF_WINDOWS = (5, 8, 11)
_MAX_TRIED_HALF_WINDOW_PER_SPACING = 0.75
_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
CLASSIC = "findChessboardCorners"
SECTOR = "findChessboardCornersSB"
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


def _found(corners: np.ndarray | None) -> np.ndarray:
    return np.asarray(corners, np.float32).reshape(-1, 1, 2)


def _stretched(grey: np.ndarray) -> np.ndarray:
    """The image's grey levels between its 0.5th and 99.5th percentile spread over 0-255 (a
    linear stretch: cornerSubPix finds the same corners in it)."""
    low, high = np.percentile(grey, (0.5, 99.5))
    scale = 255.0 / max(float(high - low), 1.0)
    return cv2.convertScaleAbs(grey, alpha=scale, beta=-float(low) * scale)


def find_chessboard(grey: np.ndarray, inner: tuple[int, int]) -> tuple[np.ndarray, str] | None:
    """The board's inner corners as first found (n×1×2, float32) and which detector found
    them (its OpenCV name, with the flags and stretch that took); ``None`` when no detector
    sees the board whole.

    The classic detector first; where it fails, the sector-based one with ``ACCURACY`` alone
    (``NORMALIZE_IMAGE`` loses dark, low-contrast boards), then ``EXHAUSTIVE``; on a dim image
    both again after a contrast stretch."""
    for image, stretched in ((grey, False), (_stretched(grey), True)):
        if stretched and float(np.percentile(grey, 99.5) - np.percentile(grey, 0.5)) > 200:
            break  # the stretch would not change the image
        suffix = " (contrast stretched)" if stretched else ""
        found, corners = cv2.findChessboardCorners(image, inner, flags=_CLASSIC_FLAGS)
        if found:
            return _found(corners), f"{CLASSIC}{suffix}"
        for flags, name in (
            (cv2.CALIB_CB_ACCURACY, SECTOR),
            (cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE, f"{SECTOR} exhaustive"),
        ):
            found, corners = cv2.findChessboardCornersSB(image, inner, flags=flags)
            if found:
                return _found(corners), f"{name}{suffix}"
    return None


def seen_quickly(grey: np.ndarray, inner: tuple[int, int]) -> bool:
    """Whether a quick look finds the board whole (fractions of a second where
    :func:`find_chessboard` takes seconds to give up): the classic detector with its fast
    check, then the sector-based one, on the contrast-stretched image when it is dim."""
    if float(np.percentile(grey, 99.5) - np.percentile(grey, 0.5)) <= 200:
        grey = _stretched(grey)
    flags = _CLASSIC_FLAGS | cv2.CALIB_CB_FAST_CHECK
    return bool(
        cv2.findChessboardCorners(grey, inner, flags=flags)[0]
        or cv2.findChessboardCornersSB(grey, inner, flags=cv2.CALIB_CB_ACCURACY)[0]
    )


def canonical(corners: np.ndarray, inner: tuple[int, int]) -> np.ndarray:
    """The corners (n×2) numbered as the board is seen from its front (rows then columns of
    object points map to image directions without a mirror) and with the rows running as
    close to the image's +x as the board's symmetry allows: one numbering for both eyes and
    all views of a board, including a square one (OpenCV may number it turned or mirrored)."""
    nx, ny = inner
    grid = corners.reshape(ny, nx, 2)
    along_x = (grid[:, -1] - grid[:, 0]).mean(axis=0)
    along_y = (grid[-1] - grid[0]).mean(axis=0)
    if along_x[0] * along_y[1] - along_x[1] * along_y[0] < 0:  # mirrored numbering
        grid = grid[::-1] if nx != ny else grid.transpose(1, 0, 2)
    options = _numberings(grid.reshape(-1, 2), inner)
    direction = [
        (o.reshape(-1, nx, 2)[:, -1] - o.reshape(-1, nx, 2)[:, 0]).mean(axis=0) for o in options
    ]
    return options[int(np.argmax([d[0] / (np.linalg.norm(d) + 1e-12) for d in direction]))]


def subpix_windows(spacing_px: float) -> list[int]:
    """cornerSubPix half-sizes to try for corners ``spacing_px`` apart: the adaptive
    :func:`half_window` first, then OpenCV's 5, 8 and 11 where the window stays within
    :data:`_MAX_TRIED_HALF_WINDOW_PER_SPACING` of the spacing."""
    first = half_window(spacing_px)
    limit = _MAX_TRIED_HALF_WINDOW_PER_SPACING * spacing_px
    return [first] + [h for h in _TRIED_HALF_WINDOWS if h != first and h <= limit]


def refine(grey: np.ndarray, corners: np.ndarray, half: int) -> np.ndarray:
    """``cornerSubPix`` of the corners (n×2) in a window of half-size ``half``."""
    start = np.asarray(corners, np.float32).reshape(-1, 1, 2).copy()
    return (
        cv2.cornerSubPix(grey, start, (half, half), (-1, -1), _SUBPIX_CRITERIA)
        .reshape(-1, 2)
        .astype(np.float64)
    )


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
