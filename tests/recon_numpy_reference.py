"""The numpy/OpenCV formulation of the decoder (colour normalisation, run/symbol/vote step), of
the De Bruijn verification and its coded region, of SGBM's fixed-point conversion and of the edge
share that the compiled loops (``vbfe.recon.kernels``) replaced: the reference the tests hold them
to, bit for bit."""

import cv2
import numpy as np

from vbfe.drivers.projector.pattern import N_SYMBOLS, WINDOW
from vbfe.recon.color import DARK_FRACTION, MIN_SIGNAL, ColorModel
from vbfe.recon.decode import BOUNDARY_DEPTH, MIN_FRINGE_VALUE, MIN_PURITY, MIN_VOTES, FringeDecoder
from vbfe.recon.kernels import BOUNDARY_TOLERANCE_PX
from vbfe.recon.verify import (
    MIN_REGION_READABLE,
    NEIGHBOUR_OFFSETS,
    REGION_FRINGES,
    REGION_REACH_FRINGES,
)


def decode_index(decoder: FringeDecoder, image: np.ndarray, period_px: float) -> np.ndarray:
    """Fringe index map of ``image`` (as ``decoder.decode``) computed with numpy."""
    height = image.shape[0]
    step = decoder.row_step
    middle = [
        min(first + (step - 1) // 2, (first + height - 1) // 2) for first in range(0, height, step)
    ]  # of each block of step rows
    image = np.ascontiguousarray(image[middle])
    window = max(3, int(round(3.5 * period_px)))
    colour = correct(decoder.color_model, image, window)
    np.maximum(colour, 0.0, out=colour)
    value = cv2.transform(colour, np.ones((1, 3), np.float32))
    value = cv2.GaussianBlur(value, (5, 1), sigmaX=max(0.5, period_px / 8))
    kernel = np.ones((1, max(3, int(round(period_px)) | 1)), np.uint8)
    local_max = cv2.dilate(value, kernel)
    starts = np.zeros(value.shape, bool)
    centre = value[:, 1:-1]
    starts[:, 1:-1] = (
        (centre < value[:, :-2])
        & (centre <= value[:, 2:])
        & (centre < BOUNDARY_DEPTH * local_max[:, 1:-1])
    )
    starts[:, 0] = True
    starts = np.flatnonzero(starts)
    counts = np.diff(np.append(starts, value.size))
    sums = np.add.reduceat(colour.reshape(-1, 3), starts, axis=0)
    brightness = np.add.reduceat(value.ravel(), starts) / counts
    b, g, r = sums.T
    top = np.maximum(np.maximum(b, g), r)
    second = b + g + r - top - np.minimum(np.minimum(b, g), r)
    purity = (top - second) / np.maximum(top, 1e-6)
    symbols = decoder._channel_symbol[np.argmax(sums, axis=1)].astype(np.int16)
    symbols[(brightness < MIN_FRINGE_VALUE) | (purity < MIN_PURITY) | (counts < 2)] = -1
    is_start = np.zeros(value.size, np.int32)
    is_start[starts] = 1
    labels = np.cumsum(is_start, dtype=np.int32) - 1
    index = _vote(decoder.lookup, symbols, starts, image.shape[1])[labels].reshape(value.shape)
    return np.repeat(index, decoder.row_step, axis=0)[:height]


def correct(model: ColorModel, image: np.ndarray, window_px: int) -> np.ndarray:
    """``model.correct(image, albedo_window_px=window_px)`` with OpenCV."""
    signal = cv2.subtract(image, tuple(float(v) for v in model.offset) + (0.0,))
    unmix = np.linalg.inv(model.mixing) * np.diag(model.mixing)
    return cv2.transform(remove_base_color(signal, window_px), unmix.astype(np.float32))


def remove_base_color(signal: np.ndarray, window_px: int) -> np.ndarray:
    """``vbfe.recon.color.remove_base_color`` with OpenCV's filters and numpy's percentile."""
    kernel = np.ones((1, window_px | 1), np.uint8)
    smooth = (window_px | 1, 3)
    low = cv2.blur(cv2.erode(signal, kernel), smooth)
    span = cv2.subtract(cv2.blur(cv2.dilate(signal, kernel), smooth), low, dtype=cv2.CV_32F)
    floor = np.maximum(
        DARK_FRACTION * np.percentile(span[::8, ::8].reshape(-1, 3), 99, axis=0), MIN_SIGNAL
    ).astype(np.float32)
    span = cv2.max(span, (*floor.tolist(), 0.0))
    return cv2.divide(cv2.subtract(signal, low, dtype=cv2.CV_32F), span)


def disparity_px(raw: np.ndarray, min_disparity: int) -> np.ndarray:
    """StereoSGBM's fixed-point disparities in pixels, NaN below ``min_disparity``."""
    return np.where(raw < min_disparity * 16, np.float32(np.nan), raw / np.float32(16))


def edge_fraction(disparity: np.ndarray, low: int, high: int) -> float:
    """Share of finite disparities within one pixel of either end of ``low..high``."""
    matched = np.count_nonzero(np.isfinite(disparity))
    at_edge = np.count_nonzero(disparity <= low + 1) + np.count_nonzero(disparity >= high - 1)
    return float(at_edge / matched) if matched else 0.0


def _vote(lookup, symbols, starts, width):
    n_segments = len(starts)
    starts_at_row = starts % width == 0
    n_windows = n_segments - WINDOW + 1
    code = np.zeros(n_windows, np.int64)
    ok = np.ones(n_windows, bool)
    for k in range(WINDOW):
        part = symbols[k : k + n_windows]
        ok &= part >= 0
        if k > 0:
            ok &= ~starts_at_row[k : k + n_windows]
        code += np.maximum(part, 0).astype(np.int64) * N_SYMBOLS**k
    first = np.where(ok, lookup[code], -1)
    candidates = np.full((WINDOW, n_segments), -1, np.int32)
    for offset in range(WINDOW):
        candidates[offset, offset : offset + n_windows] = np.where(first >= 0, first + offset, -1)
    best = np.full(n_segments, -1, np.int16)
    best_votes = np.zeros(n_segments, np.int8)
    for offset in range(WINDOW):
        votes = (candidates == candidates[offset]).sum(axis=0)
        better = (candidates[offset] >= 0) & (votes > best_votes)
        best[better] = candidates[offset, better]
        best_votes[better] = votes[better]
    best[best_votes < MIN_VOTES] = -1
    return best


def verify(disparity, left, right, search_px):
    """Verified disparity (NaN where rejected) with every unreadable left code rejected."""
    height, width = disparity.shape
    matched = np.isfinite(disparity)
    readable = matched & (left.index >= 0)
    map_x = np.arange(width, dtype=np.float32) - disparity
    cv2.patchNaNs(map_x, -10.0)
    row_map = np.repeat(np.arange(height, dtype=np.float32)[:, None], width, axis=1)
    matched_xy, _ = cv2.convertMaps(map_x, row_map, cv2.CV_16SC2, nninterpolation=True)
    tol = BOUNDARY_TOLERANCE_PX
    padded = cv2.copyMakeBorder(
        right.index.astype(np.int16), 0, 0, tol, tol, cv2.BORDER_CONSTANT, value=-2
    )
    kept = np.zeros((height, width), bool)
    for start in range(2 * tol + 1):
        code = cv2.remap(
            padded[:, start : start + width],
            matched_xy,
            None,
            cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=-2,
        )
        kept |= code == left.index
    kept &= readable
    out = np.where(kept, disparity, np.float32(np.nan))
    rows, cols = np.divmod(np.flatnonzero(readable & ~kept), width)
    out[rows, cols] = _search(
        disparity, left, right, rows, cols, disparity[rows, cols], left.index[rows, cols], search_px
    )
    return out


def _right_code(index, rows, x):
    xi = np.rint(x).astype(np.int64)
    inside = (xi >= 0) & (xi < index.shape[1])
    out = np.full(len(rows), -2, np.int32)
    out[inside] = index[rows[inside], xi[inside]]
    return out


def _search(disparity, left, right, rows, cols, d, code, search_px):
    height, width = disparity.shape
    shifts = [d + k for k in range(-search_px, search_px + 1) if k]
    for dy, dx in NEIGHBOUR_OFFSETS:
        shifts.append(
            disparity[np.clip(rows + dy, 0, height - 1), np.clip(cols + dx, 0, width - 1)]
        )
    candidates = np.stack(shifts, axis=1)
    n, k = candidates.shape
    rr = np.repeat(rows, k)
    xr = (cols[:, None] - candidates).ravel()
    finite = np.isfinite(xr)
    xr = np.where(finite, xr, -1.0)
    same = (_right_code(right.index, rr, xr) == np.repeat(code, k)) & finite
    cost = np.full(n * k, np.inf)
    cost[same] = _colour_cost(left, right, rr[same], np.repeat(cols, k)[same], xr[same])
    cost = cost.reshape(n, k) + 1e-3 * np.abs(np.nan_to_num(candidates - d[:, None], nan=0.0))
    best = np.argmin(cost, axis=1)
    found = np.isfinite(cost[np.arange(n), best])
    return np.where(found, candidates[np.arange(n), best], np.nan).astype(np.float32)


def _colour_cost(left, right, rows, xl, xr):
    width = left.colour.shape[1]
    xr = np.rint(xr).astype(np.int64)
    left_rows, right_rows = rows // left.row_step, rows // right.row_step
    total = np.zeros(len(rows), np.float32)
    for dx in (-1, 0, 1):
        a = left.colour[left_rows, np.clip(xl + dx, 0, width - 1)]
        b = right.colour[right_rows, np.clip(xr + dx, 0, width - 1)]
        total += np.abs(a - b).sum(axis=1)
    return total


def coded_region(index: np.ndarray, period_px: float) -> np.ndarray:
    """The coded region as a full-size map: cell grid resized back to the image with OpenCV."""
    height, width = index.shape
    cell = max(1, int(period_px // 2))
    cells = (max(1, width // cell), max(1, height // cell))
    readable = cv2.resize(cv2.compare(index, 0, cv2.CMP_GE), cells, interpolation=cv2.INTER_AREA)
    side = 2 * REGION_FRINGES + 1
    share = cv2.blur(readable, (side, side), borderType=cv2.BORDER_REPLICATE)
    solid = cv2.compare(share, 255 * MIN_REGION_READABLE, cv2.CMP_GE)
    reach = 2 * 2 * REGION_REACH_FRINGES + 1
    near = cv2.dilate(solid, np.ones((reach, reach), np.uint8))
    return cv2.resize(near, (width, height), interpolation=cv2.INTER_NEAREST) > 0
