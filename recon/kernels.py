"""Compiled per-pixel loops of the reconstruction (numba, cached on disk): the decoder's colour
normalisation, fringe runs, symbols and votes, SGBM's fixed-point conversion and edge share, the
De Bruijn verification and the triangulation.

Each loop reproduces, bit for bit, the numpy/OpenCV formulation it replaced (float32 arithmetic
in numpy's order, including the pairwise summation of ``np.add.reduceat``; OpenCV's filter
borders and rounding), so outputs do not depend on which one ran (tests/recon_numpy_reference.py
holds the formulations). Loops that divide use numba's numpy error model (no check for division
by zero, which none of them can meet, so the loops vectorise). Compiled code is cached next to
this file (``cache=True``); call :func:`warm_up` before any timed loop so the first frame does
not pay for loading it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

PAIRWISE_BLOCK = 128  # numpy's PW_BLOCKSIZE

# per-pixel outcome of matching and verification (the quality map)
NO_MATCH = 0  # no disparity: SGBM found none, or the match is at or beyond infinity
REJECTED = 1  # SGBM matched, but on another fringe than the left pixel's, with no repair
UNVERIFIED = 2  # SGBM's match, kept where the pattern cannot be read (or without verification)
KEPT = 3  # SGBM's match, on the left pixel's fringe
CORRECTED = 4  # replaced by a nearby candidate on the left pixel's fringe

# a match is on the left pixel's fringe when a right pixel this close to it has its code
# (fringe boundaries fall between pixels differently in the two views); compiled in as a constant
BOUNDARY_TOLERANCE_PX = 1


@njit(cache=True, nogil=True)
def _pairwise_block(a, lo, n, k):
    """``a[lo:lo+n, k]`` (``n <= PAIRWISE_BLOCK``) summed in numpy's pairwise order (float32)."""
    if n < 8:
        res = np.float32(0.0)
        for i in range(lo, lo + n):
            res += a[i, k]
        return res
    r0, r1, r2, r3 = a[lo, k], a[lo + 1, k], a[lo + 2, k], a[lo + 3, k]
    r4, r5, r6, r7 = a[lo + 4, k], a[lo + 5, k], a[lo + 6, k], a[lo + 7, k]
    i = lo + 8
    stop = lo + n - n % 8
    while i < stop:
        r0 += a[i, k]
        r1 += a[i + 1, k]
        r2 += a[i + 2, k]
        r3 += a[i + 3, k]
        r4 += a[i + 4, k]
        r5 += a[i + 5, k]
        r6 += a[i + 6, k]
        r7 += a[i + 7, k]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < lo + n:
        res += a[i, k]
        i += 1
    return res


@njit(cache=True, nogil=True)
def _pairwise_sum(a, lo, n, k):
    """``a[lo:lo+n, k]`` summed in numpy's pairwise order: halves of long runs recursively."""
    if n <= PAIRWISE_BLOCK:
        return _pairwise_block(a, lo, n, k)
    half = n // 2
    half -= half % 8
    return _pairwise_sum(a, lo, half, k) + _pairwise_sum(a, lo + half, n - half, k)


@njit(cache=True, nogil=True)
def _run_sum(a, lo, n, k):
    """``np.add.reduceat``'s sum of one run of column ``k`` of ``a`` (W×C): its first element
    plus the pairwise rest."""
    if n - 1 <= PAIRWISE_BLOCK:
        return a[lo, k] + _pairwise_block(a, lo + 1, n - 1, k)
    return a[lo, k] + _pairwise_sum(a, lo + 1, n - 1, k)


@njit(cache=True, nogil=True)
def _short_run_sums(a, lo, n):
    """``_run_sum`` of the three columns of ``a`` (W×3) at once, for runs of at most
    ``PAIRWISE_BLOCK + 1`` (a fringe): one pass over the run, numpy's order per column."""
    first, m = lo + 1, n - 1
    if m < 8:
        t0, t1, t2 = np.float32(0.0), np.float32(0.0), np.float32(0.0)
        for i in range(first, first + m):
            t0 += a[i, 0]
            t1 += a[i, 1]
            t2 += a[i, 2]
        return a[lo, 0] + t0, a[lo, 1] + t1, a[lo, 2] + t2
    b0, b1, b2, b3 = a[first, 0], a[first + 1, 0], a[first + 2, 0], a[first + 3, 0]
    b4, b5, b6, b7 = a[first + 4, 0], a[first + 5, 0], a[first + 6, 0], a[first + 7, 0]
    g0, g1, g2, g3 = a[first, 1], a[first + 1, 1], a[first + 2, 1], a[first + 3, 1]
    g4, g5, g6, g7 = a[first + 4, 1], a[first + 5, 1], a[first + 6, 1], a[first + 7, 1]
    r0, r1, r2, r3 = a[first, 2], a[first + 1, 2], a[first + 2, 2], a[first + 3, 2]
    r4, r5, r6, r7 = a[first + 4, 2], a[first + 5, 2], a[first + 6, 2], a[first + 7, 2]
    i = first + 8
    stop = first + m - m % 8
    while i < stop:
        b0, b1, b2, b3 = b0 + a[i, 0], b1 + a[i + 1, 0], b2 + a[i + 2, 0], b3 + a[i + 3, 0]
        b4, b5, b6, b7 = b4 + a[i + 4, 0], b5 + a[i + 5, 0], b6 + a[i + 6, 0], b7 + a[i + 7, 0]
        g0, g1, g2, g3 = g0 + a[i, 1], g1 + a[i + 1, 1], g2 + a[i + 2, 1], g3 + a[i + 3, 1]
        g4, g5, g6, g7 = g4 + a[i + 4, 1], g5 + a[i + 5, 1], g6 + a[i + 6, 1], g7 + a[i + 7, 1]
        r0, r1, r2, r3 = r0 + a[i, 2], r1 + a[i + 1, 2], r2 + a[i + 2, 2], r3 + a[i + 3, 2]
        r4, r5, r6, r7 = r4 + a[i + 4, 2], r5 + a[i + 5, 2], r6 + a[i + 6, 2], r7 + a[i + 7, 2]
        i += 8
    b = ((b0 + b1) + (b2 + b3)) + ((b4 + b5) + (b6 + b7))
    g = ((g0 + g1) + (g2 + g3)) + ((g4 + g5) + (g6 + g7))
    r = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < first + m:
        b, g, r = b + a[i, 0], g + a[i, 1], r + a[i, 2]
        i += 1
    return a[lo, 0] + b, a[lo, 1] + g, a[lo, 2] + r


@njit(cache=True, nogil=True)
def _shifted_max(src, offset, n, dst):
    """``dst[j] = max(src[j], src[j + offset])`` for ``j < n`` (vectorised, as below)."""
    a, b = src[:n], src[offset : offset + n]
    for j in range(n):
        dst[j] = max(a[j], b[j])


@njit(cache=True, nogil=True)
def _row_dilate(row, half, ext, tmp, out):
    """OpenCV's dilate of a float32 row by ``2·half + 1`` pixels (pixels beyond the ends take
    no part), by doubling the span of running maxima."""
    n = out.shape[0]
    size = 2 * half + 1
    total = n + 2 * half
    tail = ext[half + n : total]
    for j in range(half):
        ext[j] = tail[j] = -np.inf
    body = ext[half : half + n]
    for j in range(n):
        body[j] = row[j]
    span = 1
    swapped = False
    while 2 * span <= size:
        total -= span
        if swapped:
            _shifted_max(tmp, span, total, ext)
        else:
            _shifted_max(ext, span, total, tmp)
        swapped = not swapped
        span *= 2
    _shifted_max(tmp if swapped else ext, size - span, n, out)


@njit(cache=True, nogil=True, error_model="numpy")
def decode_rows(
    value,
    colour,
    max_half,
    lookup,
    channel_symbol,
    boundary_depth,
    min_value,
    min_purity,
    n_symbols,
    window,
    min_votes,
    row_step,
    index,
):
    """Fringe index of every pixel (into ``index``, H×W int16, -1 unreadable) from the
    decoded rows' brightness ``value`` (rows×W×1) and corrected ``colour`` (rows×W×3); the
    local maximum a boundary is judged against is over ``2·max_half + 1`` pixels (OpenCV's
    dilate); each decoded row fills the ``row_step`` image rows from its own down."""
    rows, width = value.shape[:2]
    height = index.shape[0]
    depth = np.float32(boundary_depth)
    purity_limit = np.float32(min_purity)
    tiny = np.float32(1e-6)
    starts = np.empty(width + 1, np.int64)
    symbols = np.empty(width, np.int16)
    first = np.empty(width, np.int32)
    candidates = np.empty(window, np.int32)
    ext, tmp, local_max = (
        np.empty(width + 2 * max_half, np.float32),
        np.empty(width + 2 * max_half, np.float32),
        np.empty(width, np.float32),
    )
    for r in range(rows):
        v = value[r]
        row_colour = colour[r]
        decoded = index[r * row_step]
        _row_dilate(v[:, 0], max_half, ext, tmp, local_max)
        n = 1
        starts[0] = 0
        for x in range(1, width - 1):
            c = v[x, 0]
            if c < v[x - 1, 0] and c <= v[x + 1, 0] and c < depth * local_max[x]:
                starts[n] = x
                n += 1
        starts[n] = width
        for j in range(n):
            lo = starts[j]
            count = starts[j + 1] - lo
            if count - 1 <= PAIRWISE_BLOCK:
                b, g, rd = _short_run_sums(row_colour, lo, count)
            else:
                b, g, rd = (
                    _run_sum(row_colour, lo, count, 0),
                    _run_sum(row_colour, lo, count, 1),
                    _run_sum(row_colour, lo, count, 2),
                )
            brightness = np.float64(_run_sum(v, lo, count, 0)) / count
            channel, top = 0, b
            if g > top:
                channel, top = 1, g
            if rd > top:
                channel, top = 2, rd
            second = b + g + rd - top - min(min(b, g), rd)
            purity = (top - second) / max(top, tiny)
            symbols[j] = (
                -1
                if (brightness < min_value or purity < purity_limit or count < 2)
                else channel_symbol[channel]
            )
        n_windows = n - window + 1
        for w in range(max(n_windows, 0)):
            code, weight, ok = 0, 1, True
            for k in range(window):
                s = symbols[w + k]
                ok = ok and s >= 0
                code += max(s, 0) * weight
                weight *= n_symbols
            first[w] = lookup[code] if ok else -1
        for j in range(n):
            for o in range(window):
                w = j - o
                candidates[o] = first[w] + o if 0 <= w < n_windows and first[w] >= 0 else -1
            best, best_votes = -1, 0
            for o in range(window):
                if candidates[o] >= 0:
                    votes = 0
                    for p in range(window):
                        votes += candidates[p] == candidates[o]
                    if votes > best_votes:
                        best, best_votes = candidates[o], votes
            if best_votes < min_votes:
                best = -1
            run = decoded[starts[j] : starts[j + 1]]
            for x in range(run.shape[0]):
                run[x] = best
        for y in range(r * row_step + 1, min((r + 1) * row_step, height)):
            below = index[y]
            for x in range(width):
                below[x] = decoded[x]


@njit(cache=True, nogil=True)
def _shifted_extrema(src_min, src_max, offset, n, dst_min, dst_max):
    """``dst[j] = min/max(src[j], src[j + offset])`` for ``j < n`` (the shifted operand is a
    view, so no index may wrap around and the loops vectorise)."""
    a, b = src_min[:n], src_min[offset : offset + n]
    for j in range(n):
        dst_min[j] = min(a[j], b[j])
    a, b = src_max[:n], src_max[offset : offset + n]
    for j in range(n):
        dst_max[j] = max(a[j], b[j])


@njit(cache=True, nogil=True)
def _row_extrema(row, half, ext_min, ext_max, tmp_min, tmp_max, low, high):
    """OpenCV's erode and dilate of a flat B, G, R row by ``2·half + 1`` pixels (pixels beyond
    the ends take no part), by doubling the span of running extrema."""
    n = row.shape[0]
    pad = 3 * half
    size = 2 * half + 1
    total = n + 2 * pad
    min_tail, max_tail = ext_min[pad + n : total], ext_max[pad + n : total]
    for j in range(pad):
        ext_min[j] = min_tail[j] = 255
        ext_max[j] = max_tail[j] = 0
    min_body, max_body = ext_min[pad : pad + n], ext_max[pad : pad + n]
    for j in range(n):
        min_body[j] = max_body[j] = row[j]
    span = 1  # the extrema at j are over span pixels from j
    swapped = False
    while 2 * span <= size:
        total -= 3 * span
        if swapped:
            _shifted_extrema(tmp_min, tmp_max, 3 * span, total, ext_min, ext_max)
        else:
            _shifted_extrema(ext_min, ext_max, 3 * span, total, tmp_min, tmp_max)
        swapped = not swapped
        span *= 2
    if swapped:
        _shifted_extrema(tmp_min, tmp_max, 3 * (size - span), n, low, high)
    else:
        _shifted_extrema(ext_min, ext_max, 3 * (size - span), n, low, high)


@njit(cache=True, nogil=True)
def _reflect101(i, n):
    """OpenCV's BORDER_REFLECT_101 index of ``i`` in ``0..n-1``."""
    if n == 1:
        return 0
    while i < 0 or i >= n:
        i = -i if i < 0 else 2 * n - 2 - i
    return i


@njit(cache=True, nogil=True, error_model="numpy")
def _box_mean_row(above, centre, below, half, padded, prefix, out):
    """OpenCV's uint8 box filter over three rows and ``2·half + 1`` pixels (reflect-101
    borders) of flat B, G, R rows: the sum over ``area`` pixels rounded to the nearest integer
    (``area`` is odd, so there is no tie; float32 is exact here: its error, < 3e-5, is far
    below the 1/(2·area) between a mean and a rounding boundary)."""
    n = out.shape[0]
    width = n // 3
    pad = 3 * half
    body = padded[pad : pad + n]
    for j in range(n):
        body[j] = np.int32(above[j]) + np.int32(centre[j]) + np.int32(below[j])
    for x in range(1, half + 1):
        left, right = _reflect101(-x, width), _reflect101(width - 1 + x, width)
        for c in range(3):
            padded[pad - 3 * x + c] = body[3 * left + c]
            padded[pad + n + 3 * (x - 1) + c] = body[3 * right + c]
    prefix[0] = prefix[1] = prefix[2] = 0
    for j in range(n + 2 * pad):
        prefix[j + 3] = prefix[j] + padded[j]
    ahead = prefix[3 * (2 * half + 1) :]
    area = 3 * (2 * half + 1)
    scale = np.float32(1.0 / (2 * area))
    for j in range(n):
        out[j] = np.uint8(np.int32(np.float32(2 * (ahead[j] - prefix[j]) + area) * scale))


@njit(cache=True, nogil=True, error_model="numpy")
def local_range(signal, half, low, high):
    """``low`` and ``high`` (uint8, like ``signal``, rows×W×3): OpenCV's
    ``blur(erode(signal, 1×k), (k, 3))`` and the same of ``dilate``, ``k = 2·half + 1``, with
    its default borders; rows are filtered as they are needed (three at a time)."""
    rows, width = signal.shape[:2]
    n = 3 * width
    flat, low_rows, high_rows = (
        signal.reshape(rows, n),
        low.reshape(rows, n),
        high.reshape(rows, n),
    )
    ext_min, ext_max = np.empty(n + 6 * half, np.uint8), np.empty(n + 6 * half, np.uint8)
    tmp_min, tmp_max = np.empty(n + 6 * half, np.uint8), np.empty(n + 6 * half, np.uint8)
    eroded, dilated = np.empty((3, n), np.uint8), np.empty((3, n), np.uint8)  # by row % 3
    padded = np.empty(n + 6 * half, np.int32)
    prefix = np.empty(n + 6 * half + 3, np.int32)
    for r in range(rows):
        for q in range(r if r == 0 else r + 1, min(r + 2, rows)):
            _row_extrema(
                flat[q], half, ext_min, ext_max, tmp_min, tmp_max, eroded[q % 3], dilated[q % 3]
            )
        above, below = _reflect101(r - 1, rows) % 3, _reflect101(r + 1, rows) % 3
        _box_mean_row(
            eroded[above], eroded[r % 3], eroded[below], half, padded, prefix, low_rows[r]
        )
        _box_mean_row(
            dilated[above], dilated[r % 3], dilated[below], half, padded, prefix, high_rows[r]
        )


@njit(cache=True, nogil=True)
def range_order_statistics(low, high, step, rank):
    """Per channel, the ``rank``-th and next smallest of ``high - low`` (ints, 3×2) over every
    ``step``-th row and column, by histogram (the values are integers in -255..255)."""
    counts = np.zeros((3, 511), np.int64)
    rows, width = low.shape[:2]
    n = 0
    for y in range(0, rows, step):
        for x in range(0, width, step):
            n += 1
            for c in range(3):
                counts[c, 255 + np.int32(high[y, x, c]) - np.int32(low[y, x, c])] += 1
    stats = np.empty((3, 2), np.int64)
    for c in range(3):
        seen, k = 0, 0
        for value in range(511):
            seen += counts[c, value]
            while k < 2 and seen > min(rank + k, n - 1):
                stats[c, k] = value - 255
                k += 1
    return stats


@njit(cache=True, nogil=True, error_model="numpy")
def normalise_range(signal, low, high, floor, out, clamp, value):
    """``(signal - low) / max(high - low, floor)`` per channel, float32 (rows×W×3), as
    OpenCV's subtract, max and divide compute it; ``floor`` (3 float32) is positive. With
    ``clamp``, row by row as it is computed, :func:`clamp_and_sum` into ``value``."""
    rows, width = signal.shape[:2]
    n = 3 * width
    floors = np.empty(n, np.float32)
    for j in range(n):
        floors[j] = floor[j % 3]
    flat, low_rows, high_rows, out_rows = (
        signal.reshape(rows, n),
        low.reshape(rows, n),
        high.reshape(rows, n),
        out.reshape(rows, n),
    )
    for r in range(rows):
        s, lo, hi, o = flat[r], low_rows[r], high_rows[r], out_rows[r]
        for j in range(n):
            base = np.float32(lo[j])
            span = np.float32(hi[j]) - base
            span = span if span > floors[j] else floors[j]  # noqa: FURB136 (as OpenCV)
            o[j] = (np.float32(s[j]) - base) / span
        if clamp:
            clamp_and_sum(out[r : r + 1], value[r : r + 1])


@njit(cache=True, nogil=True)
def clamp_and_sum(colour, value):
    """``colour = max(colour, 0)`` in place and ``value = (b + g) + r`` (float32, rows×W), as
    OpenCV's max and channel-summing transform compute them."""
    rows, width = colour.shape[:2]
    zero = np.float32(0.0)
    flat = colour.reshape(rows, 3 * width)
    for r in range(rows):
        c, v = flat[r], value[r]
        for j in range(3 * width):
            c[j] = c[j] if c[j] > zero else zero  # noqa: FURB136 (OpenCV's select)
        for x in range(width):
            v[x] = (c[3 * x] + c[3 * x + 1]) + c[3 * x + 2]


@njit(cache=True, nogil=True)
def fixed_point_to_px(raw, scale, min_raw, low, high, out):
    """StereoSGBM's fixed-point disparities (int16) in pixels (float32 ``raw · scale``, exact
    for a power-of-two scale), NaN below ``min_raw`` (no match). Returns the matched pixels and
    those of them at or below ``low`` or at or above ``high`` (fixed point, like ``raw``; per-row
    int32 counts keep the loop vectorised)."""
    rows, width = raw.shape
    factor = np.float32(scale)
    matched = at_edge = 0
    for y in range(rows):
        r, o = raw[y], out[y]
        row_matched = row_edge = np.int32(0)
        for x in range(width):
            v = r[x]
            o[x] = np.float32(v) * factor if v >= min_raw else np.float32(np.nan)
            row_matched += np.int32(v >= min_raw)
            row_edge += np.int32((v >= min_raw) & ((v <= low) | (v >= high)))
        matched += row_matched
        at_edge += row_edge
    return matched, at_edge


@njit(cache=True, nogil=True)
def _colour_cost(left_colour, right_colour, y_left, y_right, xl, xr):
    """Sum of absolute corrected-colour differences over 1×3 windows around xl and xr."""
    last = left_colour.shape[1] - 1
    total = np.float32(0.0)
    for dx in (-1, 0, 1):
        a = min(max(xl + dx, 0), last)
        b = min(max(xr + dx, 0), last)
        s = np.float32(0.0)
        for ch in range(3):
            s += abs(left_colour[y_left, a, ch] - right_colour[y_right, b, ch])
        total += s
    return total


@njit(cache=True, nogil=True)
def _write_match(out_row, status_row, x, d, outcome, doffs):
    """Write a match that verification let stand (``d`` finite): 1 if it makes a point
    (``d > doffs``), else 0 with NaN and ``NO_MATCH`` written."""
    if d > doffs:
        out_row[x] = d
        status_row[x] = outcome
        return 1
    out_row[x] = np.nan
    status_row[x] = NO_MATCH
    return 0


@njit(cache=True, nogil=True, error_model="numpy")
def verify_pixels(
    disparity,
    left_index,
    right_index,
    left_colour,
    right_colour,
    left_step,
    right_step,
    search_px,
    neighbours,
    coded,
    coded_rows,
    coded_cols,
    first_row,
    end_row,
    doffs_px,
    out,
    status,
):
    """Check each SGBM match against the fringe codes (see :mod:`vbfe.recon.verify`): fill
    ``out`` (disparity, NaN where invalid) and ``status`` (the codes above); ``coded`` (uint8
    cells; pixel ``(y, x)`` is cell ``(coded_rows[y], coded_cols[x])``) marks where the pattern
    is readable enough that an unreadable left code rejects a match. Only rows
    ``first_row:end_row`` are checked (and written). A disparity kept or chosen at or below
    ``doffs_px`` (at or beyond infinity) is counted as the verification decided, then written
    as NaN and ``NO_MATCH``, as :func:`count_points` does. Returns the rows' counts (SGBM
    matches, kept, corrected, rejected, unverified, and points: pixels left with a disparity
    beyond ``doffs_px``)."""
    height, width = disparity.shape
    matches = kept = corrected = rejected = unverified = points = 0
    doffs = np.float32(doffs_px)
    penalty = np.float32(1e-3)
    n_shifts = 2 * search_px
    last = width - 1
    for y in range(first_row, end_row):
        d_row, code_row, right_row = disparity[y], left_index[y], right_index[y]
        coded_row, out_row, status_row = coded[coded_rows[y]], out[y], status[y]
        for x in range(width):
            d = d_row[x]
            if not np.isfinite(d):
                out_row[x] = np.nan
                status_row[x] = NO_MATCH
                continue
            matches += 1
            code = code_row[x]
            if code < 0:
                if coded_row[coded_cols[x]]:
                    out_row[x] = np.nan
                    status_row[x] = REJECTED
                    rejected += 1
                else:
                    unverified += 1
                    points += _write_match(out_row, status_row, x, d, UNVERIFIED, doffs)
                continue
            xi = int(np.rint(np.float32(x) - d))
            on_fringe = False
            if 0 <= xi < width:  # clamped at the row's ends: the same pixels, some twice
                for k in range(-BOUNDARY_TOLERANCE_PX, BOUNDARY_TOLERANCE_PX + 1):  # unrolled
                    on_fringe |= right_row[min(max(xi + k, 0), last)] == code
            if on_fringe:
                kept += 1
                points += _write_match(out_row, status_row, x, d, KEPT, doffs)
                continue
            best, best_cost = np.float32(np.nan), np.inf
            for k in range(n_shifts + len(neighbours)):
                if k < n_shifts:
                    step = k - search_px if k < search_px else k - search_px + 1
                    candidate = d + np.float32(step)
                else:
                    offset = k - n_shifts
                    candidate = disparity[
                        min(max(y + neighbours[offset, 0], 0), height - 1),
                        min(max(x + neighbours[offset, 1], 0), width - 1),
                    ]
                cost = np.inf
                xr = np.float64(x) - np.float64(candidate)
                if np.isfinite(xr):
                    xr_i = int(np.rint(xr))
                    if 0 <= xr_i < width and right_row[xr_i] == code:
                        cost = np.float64(
                            _colour_cost(
                                left_colour, right_colour, y // left_step, y // right_step, x, xr_i
                            )
                        )
                shift = candidate - d
                cost += np.float64(
                    penalty * (abs(shift) if np.isfinite(shift) else np.float32(0.0))
                )
                if cost < best_cost:
                    best, best_cost = candidate, cost
            if np.isfinite(best_cost):
                corrected += 1
                points += _write_match(out_row, status_row, x, best, CORRECTED, doffs)
            else:
                out_row[x] = np.nan
                status_row[x] = REJECTED
                rejected += 1
    return np.array((matches, kept, corrected, rejected, unverified, points), np.int64)


@njit(cache=True, nogil=True)
def count_points(disparity, status, doffs_px, first_row, end_row):
    """Number of pixels of rows ``first_row:end_row`` with a disparity beyond ``doffs_px``;
    those at or beyond infinity get NaN and ``NO_MATCH`` in ``disparity`` and ``status``."""
    doffs = np.float32(doffs_px)
    n = 0
    for v in range(first_row, end_row):
        d_row, status_row = disparity[v], status[v]
        for u in range(disparity.shape[1]):
            d = d_row[u]
            if d > doffs:
                n += 1
            elif np.isfinite(d):
                d_row[u] = np.nan
                status_row[u] = NO_MATCH
    return n


@njit(cache=True, nogil=True, error_model="numpy")
def fill_points(
    disparity,
    status,
    image_bgr,
    f_px,
    baseline_m,
    cx,
    cy,
    doffs_px,
    fy_px,
    first_row,
    end_row,
    points,
    colours,
    verified,
    start,
):
    """Write the points of rows ``first_row:end_row`` (after :func:`count_points`) from index
    ``start`` on (see :func:`triangulate`)."""
    width = disparity.shape[1]
    doffs = np.float32(doffs_px)
    f = np.float32(f_px)
    fy = np.float32(fy_px)
    f_b = np.float32(f_px * baseline_m)
    cx32, cy32 = np.float32(cx), np.float32(cy)
    x_over_z = np.empty(width, np.float32)
    for u in range(width):
        x_over_z[u] = (np.float32(u) - cx32) / f
    z_row = np.empty(width, np.float32)
    i = start
    for v in range(first_row, end_row):
        y_over_z = (np.float32(v) - cy32) / fy
        d_row = disparity[v]
        for u in range(width):  # vectorised; used where d > doffs
            z_row[u] = f_b / (d_row[u] - doffs)
        for u in range(width):
            if d_row[u] > doffs:
                z = z_row[u]
                points[i, 0] = x_over_z[u] * z
                points[i, 1] = y_over_z * z
                points[i, 2] = z
                for ch in range(3):
                    colours[i, ch] = image_bgr[v, u, 2 - ch]
                verified[i] = status[v, u] >= KEPT
                i += 1


@njit(cache=True, nogil=True)
def triangulate(disparity, status, image_bgr, f_px, baseline_m, cx, cy, doffs_px, fy_px):
    """Points (N×3 float32, m), colours (N×3 uint8, RGB) and verified flags (N bool) of the pixels
    with a disparity beyond ``doffs_px``, in row-major order: ``z = fB/(d - doffs)``,
    ``x = (u-cx)z/f``, ``y = (v-cy)z/fy`` (``f``: the rectified focal length in x). Pixels at or
    beyond infinity get NaN and ``NO_MATCH`` in ``disparity`` and ``status``."""
    height = disparity.shape[0]
    n = count_points(disparity, status, doffs_px, 0, height)
    points = np.empty((n, 3), np.float32)
    colours = np.empty((n, 3), np.uint8)
    verified = np.empty(n, np.bool_)
    fill_points(
        disparity,
        status,
        image_bgr,
        f_px,
        baseline_m,
        cx,
        cy,
        doffs_px,
        fy_px,
        0,
        height,
        points,
        colours,
        verified,
        0,
    )
    return points, colours, verified


def warm_up() -> None:
    """Load (or, the first time, compile) every loop, so no timed call pays for it."""
    value = np.ones((2, 8, 1), np.float32)
    colour = np.ones((2, 8, 3), np.float32)
    index = np.zeros((4, 8), np.int16)
    decode_rows(
        value,
        colour,
        1,
        np.zeros(81, np.int32),
        np.zeros(3, np.int8),
        0.6,
        0.2,
        0.25,
        3,
        4,
        2,
        2,
        index,
    )
    disparity = np.ones((4, 8), np.float32)
    status = np.zeros((4, 8), np.uint8)
    verify_pixels(
        disparity,
        index,
        index,
        colour,
        colour,
        2,
        2,
        1,
        np.zeros((1, 2), np.int64),
        np.ones((1, 1), np.uint8),
        np.zeros(4, np.int32),
        np.zeros(8, np.int32),
        0,
        4,
        0.0,
        disparity.copy(),
        status,
    )
    image_bgr = np.zeros((4, 8, 3), np.uint8)
    triangulate(disparity, status, image_bgr, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    count_points(disparity, status, 0.0, 0, 4)
    fill_points(
        disparity,
        status,
        image_bgr,
        1.0,
        1.0,
        0.0,
        0.0,
        0.0,
        1.0,
        0,
        4,
        np.empty((32, 3), np.float32),
        np.empty((32, 3), np.uint8),
        np.empty(32, np.bool_),
        0,
    )
    image = np.zeros((2, 8, 3), np.uint8)
    local_range(image, 1, image.copy(), image.copy())
    for clamp in (False, True):
        normalise_range(image, image, image, np.ones(3, np.float32), colour, clamp, value[..., 0])
    clamp_and_sum(colour, value[..., 0])
    fixed_point_to_px(
        np.zeros((4, 8), np.int16), 1.0 / 16, np.int16(16), np.int16(32), np.int16(48), disparity
    )
    range_order_statistics(image, image, 8, 0)
