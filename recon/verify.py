"""De Bruijn verification of SGBM matches, where the pattern can be read.

A left pixel and its matched right pixel must lie on the same pattern fringe (same window-4
code). Matches within one pixel of a fringe with the left pixel's code are kept (fringe
boundaries fall between pixels differently in the two views). Other matches are replaced by the
candidate with the same code and the lowest colour cost among the disparities ``d ± search_px``
on the same row and the SGBM disparities of nearby pixels; matches without such a candidate are
rejected. A pixel whose own code is unreadable is rejected inside the coded region (a fringe
boundary, a shadow between fringes) and keeps SGBM's match, marked unverified, outside it (where
the pattern does not reach or cannot be read). The per-pixel loop is compiled
(:func:`vbfe.recon.kernels.verify_pixels`); its outcome per pixel is the quality map.
"""

from __future__ import annotations

import functools
from concurrent.futures import Executor
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from vbfe.recon import kernels
from vbfe.recon.decode import FringeCode

NEIGHBOUR_OFFSETS = np.array(
    ((0, -4), (0, 4), (-4, 0), (4, 0), (0, -8), (0, 8), (-8, 0), (8, 0)), np.int64
)
REGION_FRINGES = 4  # side, in fringe widths, of the square over which readability is judged
MIN_REGION_READABLE = 0.5  # share of readable codes that makes a square solidly coded
# how far, in fringe widths, the coded region reaches beyond them (over glare and shadows
# within the projection: 4 let 0.5 % bad pixels through under strong specularity, 8 none)
REGION_REACH_FRINGES = 8
# what verification counts (verify_rows adds the points left)
COUNT_NAMES = ("sgbm_matches", "kept", "corrected", "rejected", "unverified")


@lru_cache(maxsize=16)
def _nearest_source(n_source: int, n_target: int) -> np.ndarray:
    """Source index of each target index in OpenCV's nearest-neighbour resize (taken from
    OpenCV itself, by resizing a ramp)."""
    ramp = np.arange(n_source, dtype=np.int32)[None]
    source = cv2.resize(ramp, (n_target, 1), interpolation=cv2.INTER_NEAREST)[0]
    source.flags.writeable = False
    return source


@dataclass(frozen=True)
class CodedGrid:
    """The coded region on a coarse grid: pixel ``(y, x)`` is coded where
    ``cells[rows[y], cols[x]]`` is non-zero (so the full-size map is never built)."""

    cells: np.ndarray  # uint8
    rows: np.ndarray  # int32, one per image row
    cols: np.ndarray  # int32, one per image column

    @classmethod
    def of_map(cls, coded: np.ndarray) -> CodedGrid:
        """A full-size bool map as a grid of one-pixel cells."""
        height, width = coded.shape
        return cls(
            np.ascontiguousarray(coded, dtype=bool).view(np.uint8),
            np.arange(height, dtype=np.int32),
            np.arange(width, dtype=np.int32),
        )

    def full(self) -> np.ndarray:
        """The bool H×W map."""
        return self.cells.take(self.rows, axis=0).take(self.cols, axis=1) > 0


def coded_grid(code: FringeCode) -> CodedGrid:
    """:func:`coded_region` on its grid of cells of half a fringe."""
    height, width = code.index.shape
    cell = max(1, int(code.period_px // 2))
    cells = (max(1, width // cell), max(1, height // cell))
    # OpenCV compares with a scalar here; its stubs do not say so
    decoded = cv2.compare(code.index, 0, cv2.CMP_GE)  # type: ignore[call-overload]
    readable = cv2.resize(decoded, cells, interpolation=cv2.INTER_AREA)
    side = 2 * REGION_FRINGES + 1  # in cells
    share = cv2.blur(readable, (side, side), borderType=cv2.BORDER_REPLICATE)
    solid = cv2.compare(share, 255 * MIN_REGION_READABLE, cv2.CMP_GE)  # type: ignore[call-overload]
    reach = 2 * 2 * REGION_REACH_FRINGES + 1  # cells are half a fringe wide
    near = cv2.dilate(solid, np.ones((reach, reach), np.uint8))
    return CodedGrid(near, _nearest_source(cells[1], height), _nearest_source(cells[0], width))


def coded_region(code: FringeCode) -> np.ndarray:
    """Where the pattern is read (bool H×W): within ``REGION_REACH_FRINGES`` fringe widths of
    a square of ``REGION_FRINGES`` fringes in which at least ``MIN_REGION_READABLE`` of the
    codes are readable (so fringe boundaries, the unreadable run ends at the image's sides and
    glare or shadows inside the projection stay inside). Judged on cells of half a fringe."""
    return coded_grid(code).full()


def verify_rows(
    disparity: np.ndarray,
    left: FringeCode,
    right: FringeCode,
    search_px: int,
    coded: CodedGrid,
    first_row: int,
    end_row: int,
    out: np.ndarray,
    status: np.ndarray,
    doffs_px: float = -np.inf,
) -> np.ndarray:
    """Verify rows ``first_row:end_row`` into ``out`` and ``status`` (see
    :func:`verify_disparity`; matches at or below ``doffs_px``, at or beyond infinity, end as
    ``NO_MATCH``). Returns their counts: SGBM matches, kept, corrected, rejected, unverified
    and the pixels left with a disparity (the points they triangulate to)."""
    return kernels.verify_pixels(
        disparity,
        left.index,
        right.index,
        left.colour,
        right.colour,
        left.row_step,
        right.row_step,
        search_px,
        NEIGHBOUR_OFFSETS,
        coded.cells,
        coded.rows,
        coded.cols,
        first_row,
        end_row,
        doffs_px,
        out,
        status,
    )


def verify_disparity(
    disparity: np.ndarray,
    left: FringeCode,
    right: FringeCode,
    search_px: int = 3,
    coded: np.ndarray | CodedGrid | None = None,
    pool: Executor | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Verified disparity (float32, NaN where invalid), the outcome per pixel (uint8 codes of
    :mod:`vbfe.recon.kernels`: ``NO_MATCH``, ``REJECTED``, ``UNVERIFIED``, ``KEPT``,
    ``CORRECTED``) and counts of what happened.

    ``disparity`` is the left-view SGBM disparity in pixels, ``NaN`` where SGBM found none;
    ``coded`` (bool H×W or its :class:`CodedGrid`; default: :func:`coded_grid` of the left
    code) is where the pattern is read. With a ``pool``, the lower half of the rows is checked
    in it while this thread checks the upper half (the same results).
    """
    out = np.empty_like(disparity)
    status = np.empty(disparity.shape, np.uint8)
    if coded is None:
        coded = coded_grid(left)
    elif isinstance(coded, np.ndarray):
        coded = CodedGrid.of_map(coded)
    height = disparity.shape[0]
    split = height // 2 if pool is not None else height
    check = functools.partial(verify_rows, disparity, left, right, search_px, coded)
    lower = pool.submit(check, split, height, out, status) if pool is not None else None
    counts = check(0, split, out, status)
    if lower is not None:
        counts = counts + lower.result()
    return out, status, dict(zip(COUNT_NAMES, (int(c) for c in counts), strict=False))
