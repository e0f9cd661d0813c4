"""Image-vs-force offset from the corners of the force profile (sharp starts and ends of pulls).

Both streams are mapped onto the host clock (clock fits). Where the force changes slope abruptly
(the start of a pull, the start of a hold) the tissue's motion changes speed at the same instant,
so the image kinks there too. At each such *corner* the force (1 kHz) is fitted by a continuous
quadratic spline with one knot, flat on the side where the force is constant (rest, hold); the
frames (leading principal components of downscaled grey pixels) by a continuous quadratic spline
whose knot may lie up to ``max_lag`` away, slope and curvature free to change. Knot positions
come from the least-squares profile (95% interval where twice the log-likelihood stays within
3.84 of its best); the image knot minus the force knot is that corner's lag, and the
inverse-variance mean over the corners is the offset (positive: images are stamped later than
the forces of the same instant), its spread inflated when the corners disagree.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from vbfe.acquire.session.reader import SessionReader
from vbfe.common.errors import SessionError

_MOTION_WIDTH = 128  # frames are downscaled (area average) to this width
_COMPONENTS = 3  # leading principal components of the frames that carry the motion
_GRASP_WIDTH = 320  # frames are downscaled to this width to find and crop the grasp's window
_GRASP_HALF = 0.15  # half side of the grasp's square window, as a fraction of that width
_GRASP_END_FRAMES = 5  # frames averaged at each end of the session to find the window
_GRASP_BLUR = 6.0  # Gaussian blur (px at _GRASP_WIDTH) of the change map before its peak
_FORCE_SMOOTH_S = 0.01  # symmetric box over the force while looking for corners
_CORNER_GRID_S = 0.005  # the force is resampled on this grid to find its corners
_SLOPE_WINDOW_S = 0.3  # slopes before/after a candidate corner are fitted over this long
_CORNER_FRACTION = 0.25  # a corner's slope change is at least this share of the largest
_FLAT_RATIO = 0.2  # a side whose slope is below this share of the other's is flat
_FORCE_WINDOW_S = 1.2  # force samples within this of a corner are fitted
_FORCE_SEARCH_S = 0.1  # the force knot is searched this far around the detected corner
_IMAGE_WINDOW_S = 0.5  # frames within this of the image knot's search range are fitted
_MIN_FRAMES = 10  # fewer frames around a corner: the corner is skipped
_CHI2_95 = 3.841  # 95% quantile of χ² with one degree of freedom
_SEARCH_STEP_S = 0.0005  # knot positions are tried on this grid


@dataclass
class OffsetEstimate:
    """An offset (image minus force, s), its uncertainty, how it was measured and the evidence:
    the lag at each force corner, or the correlation of the change signals against lag."""

    offset_s: float
    std_s: float
    ci95_s: tuple[float, float]
    method: str  # "force corners" or "change correlation"
    corner_times_s: np.ndarray = field(default_factory=lambda: np.empty(0))  # force knots (s)
    corner_lags_s: np.ndarray = field(default_factory=lambda: np.empty(0))  # image − force knot
    corner_std_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    lags_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    correlation: np.ndarray = field(default_factory=lambda: np.empty(0))

    @property
    def corners(self) -> int:
        """Number of force corners the offset rests on."""
        return len(self.corner_lags_s)


def _grey(image: np.ndarray, max_width: int) -> np.ndarray:
    """``image`` in grey, area-downscaled to at most ``max_width``."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    scale = min(1.0, max_width / grey.shape[1])
    if scale < 1.0:
        grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    return grey


def grey_left_frames(reader: SessionReader, max_width: int) -> Iterator[np.ndarray]:
    """Every left frame of the session in grey, area-downscaled to at most ``max_width``."""
    for frame in reader.iter_frames():
        yield _grey(frame.left, max_width)


def frame_components(reader: SessionReader) -> np.ndarray:
    """Leading principal components (frames × 3, ``U·S``) of the downscaled grey left
    frames: the image's main ways of changing, with most pixel noise left out."""
    rows = [grey.ravel() for grey in grey_left_frames(reader, _MOTION_WIDTH)]
    pixels = np.asarray(rows, np.float32)
    pixels -= pixels.mean(axis=0)
    return _leading_components(pixels, _COMPONENTS)


def grasp_components(reader: SessionReader) -> np.ndarray:
    """Leading principal components (frames × 3, ``U·S``) of a square window around the grasp
    in both grey frames of each stereo pair, the two windows' pixels side by side. Each
    camera's window is where its picture changed most between the session's first and last
    frames (blurred change map). Whole-frame components mix the grasp's motion with everything
    else that changes; the window keeps the part that follows the grasp's displacement, and the
    second camera's independent pixel noise averages out of the components."""
    left, right = [], []
    for frame in reader.iter_frames():
        left.append(_grey(frame.left, _GRASP_WIDTH))
        right.append(_grey(frame.right, _GRASP_WIDTH))
    window = np.hstack([_grasp_window(np.asarray(frames, np.float32)) for frames in (left, right)])
    return _leading_components(window - window.mean(axis=0), _COMPONENTS)


def _grasp_window(frames: np.ndarray) -> np.ndarray:
    """The pixels (frames × pixels) of the square window around the grasp in ``frames``."""
    ends = min(_GRASP_END_FRAMES, len(frames))
    change = cv2.GaussianBlur(
        np.abs(frames[-ends:].mean(0) - frames[:ends].mean(0)), (0, 0), _GRASP_BLUR
    )
    cy, cx = np.unravel_index(int(np.argmax(change)), change.shape)
    half = max(2, int(round(_GRASP_HALF * frames.shape[2])))
    y0 = int(np.clip(cy - half, 0, max(0, frames.shape[1] - 2 * half)))
    x0 = int(np.clip(cx - half, 0, max(0, frames.shape[2] - 2 * half)))
    return frames[:, y0 : y0 + 2 * half, x0 : x0 + 2 * half].reshape(len(frames), -1)


def _leading_components(
    x: np.ndarray, k: int, oversample: int = 8, power_iterations: int = 3
) -> np.ndarray:
    """``U·S`` of the ``k`` leading singular vectors of ``x`` (randomized range finder with power
    iterations: a full SVD of frames × pixels is needlessly slow)."""
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(x @ rng.standard_normal((x.shape[1], k + oversample)).astype(x.dtype))
    for _ in range(power_iterations):
        q, _ = np.linalg.qr(x @ (x.T @ q))
    u, s, _ = np.linalg.svd((q.T @ x).astype(np.float64), full_matrices=False)
    return (q.astype(np.float64) @ u[:, :k]) * s[:k]


def force_axis(forces: np.ndarray) -> np.ndarray:
    """The force along its direction of largest variance (a single axis: itself, centred)."""
    f = np.atleast_2d(np.asarray(forces, np.float64).T).T
    centred = f - f.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return centred @ vt[0]


def _box(values: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average (odd width, edges held): smooths without adding a lag."""
    width |= 1
    return np.convolve(np.pad(values, width // 2, mode="edge"), np.ones(width) / width, "valid")


@dataclass(frozen=True)
class Corner:
    """An abrupt change of the force's slope; ``flat`` names a side where the force is constant
    ("before": the end of a rest, "after": the start of a hold, "": neither)."""

    time_s: float
    flat: str


def force_corners(t_s: np.ndarray, force: np.ndarray) -> list[Corner]:
    """Where the force's slope changes abruptly: line fits over ``_SLOPE_WINDOW_S`` before and
    after an instant differ by at least ``_CORNER_FRACTION`` of the largest such change."""
    grid = np.arange(t_s[0], t_s[-1], _CORNER_GRID_S)
    f = np.interp(grid, t_s, force)
    m = max(3, int(round(_SLOPE_WINDOW_S / _CORNER_GRID_S)))
    if len(grid) < 2 * m + 1:
        return []
    ramp = np.arange(m) - (m - 1) / 2
    ramp /= np.sum(ramp**2) * _CORNER_GRID_S  # slope of a least-squares line over m points
    slope = np.convolve(f, ramp[::-1], "valid")  # slope[i]: line through f[i:i+m]
    before, after = np.zeros(len(grid)), np.zeros(len(grid))
    before[m : len(slope) + 1] = slope[: len(slope) - m + 1]
    after[m : len(slope) + 1] = slope[m - 1 :]
    change = np.abs(after - before)
    if not change.any():
        return []
    from scipy.signal import find_peaks  # here: scipy.signal costs every vbfe command ~0.8 s

    peaks, _ = find_peaks(change, height=_CORNER_FRACTION * change.max(), distance=m)
    corners = []
    for i in peaks:
        lo, hi = sorted((abs(before[i]), abs(after[i])))
        flat = (
            ("before" if abs(before[i]) < abs(after[i]) else "after")
            if lo < _FLAT_RATIO * hi
            else ""
        )
        corners.append(Corner(float(grid[i]), flat))
    return corners


def _spline_designs(
    t_s: np.ndarray, knots_s: np.ndarray, scale_s: float, flat: str = ""
) -> np.ndarray:
    """Columns (knots × samples × p) of continuous quadratic splines with one knot each: slope
    and curvature may change at the knot; on a ``flat`` side ("before"/"after") it is constant."""
    s = (t_s[None, :] - knots_s[:, None]) / scale_s
    h, n = np.maximum(s, 0.0), np.minimum(s, 0.0)
    one = np.ones_like(s)
    if flat == "before":
        return np.stack([one, h, h**2], axis=2)
    if flat == "after":
        return np.stack([one, n, n**2], axis=2)
    return np.stack([one, s, s**2, h, h**2], axis=2)


def _knot_profile(
    t_s: np.ndarray, values: np.ndarray, knots_s: np.ndarray, scale_s: float, flat: str = ""
) -> tuple[float, float]:
    """Least-squares knot of a one-knot quadratic spline through ``values`` (n, or n×k columns
    with their own noise levels) among ``knots_s``: position (s) and standard error from the 95%
    profile-likelihood interval."""
    values = values.reshape(len(t_s), -1)
    design = _spline_designs(t_s, knots_s, scale_s, flat)
    normal = np.einsum("knp,knq->kpq", design, design)
    coef = np.linalg.solve(
        normal + 1e-12 * np.eye(design.shape[2]), np.einsum("knp,nc->kpc", design, values)
    )
    rss = np.sum((values[None] - design @ coef) ** 2, axis=1)
    deviance = len(t_s) * np.sum(np.log(np.maximum(rss, 1e-300)), axis=1)  # −2·log-likelihood
    k = int(np.argmin(deviance))
    inside = np.flatnonzero(deviance - deviance[k] <= _CHI2_95)
    low, high = _bounds(inside, k)
    step = float(knots_s[1] - knots_s[0])
    position = float(knots_s[0] + _vertex(deviance, k) * step)
    if low == 0 or high == len(knots_s) - 1:  # the interval runs off the search range
        return position, float("inf")
    return position, (high - low + 1) * step / (2 * 1.96)


def _bounds(inside: np.ndarray, k: int) -> tuple[int, int]:
    """The run of consecutive indices in ``inside`` that contains ``k``."""
    breaks = np.flatnonzero(np.diff(inside) > 1)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(inside) - 1]])
    run = int(np.searchsorted(inside[starts], k, side="right")) - 1
    return int(inside[starts[run]]), int(inside[ends[run]])


def _vertex(curve: np.ndarray, k: int) -> float:
    """Index of the minimum ``k`` refined by a parabola through it and its neighbours."""
    if 0 < k < len(curve) - 1:
        ym, y0, yp = curve[k - 1 : k + 2]
        denom = ym - 2 * y0 + yp
        if denom > 0:
            return k + float(np.clip(0.5 * (ym - yp) / denom, -0.5, 0.5))
    return float(k)


def _corner_lag(
    t_force: np.ndarray,
    force: np.ndarray,
    t_frames: np.ndarray,
    components: np.ndarray,
    corner: Corner,
    max_lag_s: float,
) -> tuple[float, float, float] | None:
    """Force knot, image-minus-force lag and its standard error at one corner (None: too few
    frames around it)."""
    near = np.abs(t_force - corner.time_s) <= _FORCE_WINDOW_S
    knots = corner.time_s + np.arange(-_FORCE_SEARCH_S, _FORCE_SEARCH_S + 1e-9, _SEARCH_STEP_S)
    knot, knot_std = _knot_profile(t_force[near], force[near], knots, _FORCE_WINDOW_S, corner.flat)
    reach = max_lag_s + _IMAGE_WINDOW_S
    frames = np.abs(t_frames - knot) <= reach
    if frames.sum() < _MIN_FRAMES or not (t_frames[frames][0] < knot < t_frames[frames][-1]):
        return None
    lags = np.arange(-max_lag_s, max_lag_s + 1e-9, _SEARCH_STEP_S)
    image_knot, image_std = _knot_profile(
        t_frames[frames], components[frames], knot + lags, _IMAGE_WINDOW_S
    )
    return knot, image_knot - knot, float(np.hypot(knot_std, image_std))


def corner_offset(
    t_frames_ns: np.ndarray,
    components: np.ndarray,
    t_force_ns: np.ndarray,
    forces: np.ndarray,
    max_lag_s: float = 0.25,
) -> OffsetEstimate:
    """Lag (s) by which the frames (``components``, stamped ``t_frames_ns``) follow the force.

    Raises :class:`SessionError` when the force has no corner inside the camera record.
    """
    t_force = (t_force_ns - t_force_ns[0]) / 1e9
    t_frames = (t_frames_ns - t_force_ns[0]) / 1e9
    step = float(np.median(np.diff(t_force)))
    axis = force_axis(forces)  # fitted raw: its noise is white, the knot's interval honest
    corners = force_corners(t_force, _box(axis, int(round(_FORCE_SMOOTH_S / step))))
    found = [_corner_lag(t_force, axis, t_frames, components, c, max_lag_s) for c in corners]
    found = [f for f in found if f is not None and np.isfinite(f[2])]
    if not found:
        raise SessionError(
            "the force never changes slope sharply inside the camera record (no "
            "clear start or end of a pull), so there is nothing to align the "
            "images on; record a pull with a rest before and a hold after it"
        )
    times, lags, stds = (np.array(x) for x in zip(*found, strict=False))
    weights = 1.0 / np.maximum(stds, _SEARCH_STEP_S / 2) ** 2
    offset = float(np.sum(weights * lags) / np.sum(weights))
    std = float(np.sqrt(1.0 / np.sum(weights)))
    if len(lags) > 1:  # corners that disagree beyond their errors widen the interval
        chi2 = float(np.sum(weights * (lags - offset) ** 2)) / (len(lags) - 1)
        std *= np.sqrt(max(1.0, chi2))
    return OffsetEstimate(
        offset_s=offset,
        std_s=std,
        ci95_s=(offset - 1.96 * std, offset + 1.96 * std),
        method="force corners",
        corner_times_s=times,
        corner_lags_s=lags,
        corner_std_s=stds,
    )
