"""De Bruijn verification of SGBM matches.

A left pixel and its matched right pixel must lie on the same pattern fringe (same window-4
code). Matches within one pixel of a fringe with the left pixel's code are kept (fringe
boundaries fall between pixels differently in the two views). Other matches are replaced by the
candidate with the same code and the lowest colour cost among the disparities ``d ± search_px``
on the same row and the SGBM disparities of nearby pixels; pixels without such a candidate, or
whose own code is unreadable, are invalid.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from vbfe.recon.decode import FringeCode

BOUNDARY_TOLERANCE_PX = 1
NEIGHBOUR_OFFSETS = ((0, -4), (0, 4), (-4, 0), (4, 0), (0, -8), (0, 8), (-8, 0), (8, 0))


def verify_disparity(disparity: np.ndarray, left: FringeCode, right: FringeCode,
                     search_px: int = 3) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Verified disparity (float32, NaN where invalid), valid mask and counts of what happened.

    ``disparity`` is the left-view SGBM disparity in pixels, ``NaN`` where SGBM found none.
    """
    height, width = disparity.shape
    matched = np.isfinite(disparity)
    readable = matched & (left.index >= 0)
    map_x = np.arange(width, dtype=np.float32) - disparity
    cv2.patchNaNs(map_x, -10.0)  # unmatched: outside the image
    # the matched right pixel, rounded once into OpenCV's fixed-point map; the codes around it
    # come from views of the right code map shifted by whole columns (-2 beyond its ends)
    matched_xy, _ = cv2.convertMaps(map_x, _row_map(height, width), cv2.CV_16SC2,
                                    nninterpolation=True)
    tol = BOUNDARY_TOLERANCE_PX
    padded = cv2.copyMakeBorder(right.index.astype(np.int16), 0, 0, tol, tol,
                                cv2.BORDER_CONSTANT, value=-2)
    kept = np.zeros((height, width), bool)
    for start in range(2 * tol + 1):
        code = cv2.remap(padded[:, start:start + width], matched_xy, None, cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=-2)
        kept |= code == left.index
    kept &= readable
    out = np.where(kept, disparity, np.float32(np.nan))
    rows, cols = np.divmod(np.flatnonzero(readable & ~kept), width)
    new_d = _search(disparity, left, right, rows, cols, disparity[rows, cols],
                    left.index[rows, cols], search_px)
    out[rows, cols] = new_d
    valid = np.isfinite(out)
    n_matched = np.count_nonzero(matched)
    counts = {"sgbm_matches": n_matched, "kept": np.count_nonzero(kept),
              "corrected": np.count_nonzero(np.isfinite(new_d)),
              "rejected": n_matched - np.count_nonzero(valid)}
    return out, valid, counts


@functools.lru_cache(maxsize=4)
def _row_map(height: int, width: int) -> np.ndarray:
    """The y map of a row-preserving remap (built once per image size)."""
    return np.repeat(np.arange(height, dtype=np.float32)[:, None], width, axis=1)


def _right_code(index: np.ndarray, rows: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Right-image code at (row, round(x)); -2 outside the image (never equals a code)."""
    xi = np.rint(x).astype(np.int64)
    inside = (xi >= 0) & (xi < index.shape[1])
    out = np.full(len(rows), -2, np.int32)
    out[inside] = index[rows[inside], xi[inside]]
    return out


def _search(disparity: np.ndarray, left: FringeCode, right: FringeCode, rows: np.ndarray,
            cols: np.ndarray, d: np.ndarray, code: np.ndarray, search_px: int) -> np.ndarray:
    """Best same-code disparity for each rejected match (NaN when none)."""
    height, width = disparity.shape
    shifts = [d + k for k in range(-search_px, search_px + 1) if k]
    for dy, dx in NEIGHBOUR_OFFSETS:
        shifts.append(disparity[np.clip(rows + dy, 0, height - 1),
                                np.clip(cols + dx, 0, width - 1)])
    candidates = np.stack(shifts, axis=1)  # (n, k)
    n, k = candidates.shape
    rr = np.repeat(rows, k)
    xr = (cols[:, None] - candidates).ravel()
    finite = np.isfinite(xr)
    xr = np.where(finite, xr, -1.0)
    same = (_right_code(right.index, rr, xr) == np.repeat(code, k)) & finite
    cost = np.full(n * k, np.inf)
    cost[same] = _colour_cost(left, right, rr[same], np.repeat(cols, k)[same],
                              xr[same])
    cost = cost.reshape(n, k) + 1e-3 * np.abs(np.nan_to_num(candidates - d[:, None], nan=0.0))
    best = np.argmin(cost, axis=1)
    found = np.isfinite(cost[np.arange(n), best])
    return np.where(found, candidates[np.arange(n), best], np.nan).astype(np.float32)


def _colour_cost(left: FringeCode, right: FringeCode, rows: np.ndarray, xl: np.ndarray,
                 xr: np.ndarray) -> np.ndarray:
    """Sum of absolute corrected-colour differences over 1×3 windows around xl (left) and xr."""
    width = left.colour.shape[1]
    xr = np.rint(xr).astype(np.int64)
    left_rows, right_rows = rows // left.row_step, rows // right.row_step
    total = np.zeros(len(rows), np.float32)
    for dx in (-1, 0, 1):
        a = left.colour[left_rows, np.clip(xl + dx, 0, width - 1)]
        b = right.colour[right_rows, np.clip(xr + dx, 0, width - 1)]
        total += np.abs(a - b).sum(axis=1)
    return total
