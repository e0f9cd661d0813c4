"""Image-vs-force offset from the cross-correlation of two change signals (any force profile).

Mean absolute difference of consecutive (downscaled, grey) left frames against the norm of the
force change over one frame period centred on the same instant, both on the host clock, on a
1 ms grid. The correlation peak, refined by a parabola, is the offset; a bootstrap over
force-change events (or fixed segments) gives its uncertainty and 95% confidence interval.
"""

from __future__ import annotations

import numpy as np

from vbfe.acquire.session.reader import SessionReader
from vbfe.acquire.sync.corners import OffsetEstimate, _vertex, grey_left_frames
from vbfe.common.errors import SessionError

_MOTION_WIDTH = 160  # frames are downscaled to this width before differencing
_EVENT_FRACTION = 0.25  # a segment is an event when its force change is this share of the most
_MIN_EVENTS = 3  # fewer force-change events than this: bootstrap over fixed segments
_EVENT_SPACING_S = 0.3
_MAX_STEP_PERIODS = 1.5  # frame pairs further apart than this (in periods) straddle a drop


def motion_energy(reader: SessionReader) -> tuple[np.ndarray, np.ndarray]:
    """Mean |difference| of consecutive left frames, at the midpoints of their host times."""
    times = reader.frame_times_ns()
    previous = None
    energy = np.zeros(max(reader.n_frames - 1, 0))
    for i, grey in enumerate(grey_left_frames(reader, _MOTION_WIDTH)):
        grey = grey.astype(np.float32)
        if previous is not None:
            energy[i - 1] = float(np.mean(np.abs(grey - previous)))
        previous = grey
    step = np.diff(times)
    consecutive = step <= _MAX_STEP_PERIODS * np.median(step)  # not across dropped frames
    return ((times[:-1] + times[1:]) // 2)[consecutive], energy[consecutive]


def _peak(correlation: np.ndarray) -> float:
    """Index of the maximum, refined by a parabola through it and its neighbours."""
    return _vertex(-correlation, int(np.argmax(correlation)))


def _event_bounds(change: np.ndarray, grid_s: float, segment_s: float) -> np.ndarray:
    """Cut points splitting the record into one segment per force-change event (cut at the
    quietest instant between events), or into ``segment_s`` pieces when there are few events."""
    from scipy.signal import find_peaks  # here: scipy.signal costs every vbfe command ~0.8 s

    peaks, _ = find_peaks(
        change,
        prominence=_EVENT_FRACTION * float(change.max() or 1.0),
        distance=max(1, int(_EVENT_SPACING_S / grid_s)),
    )
    if len(peaks) >= _MIN_EVENTS:
        cuts = [
            a + int(np.argmin(change[a:b])) for a, b in zip(peaks[:-1], peaks[1:], strict=False)
        ]
        return np.array([0, *cuts, len(change)])
    n_seg = max(2, int(len(change) * grid_s / segment_s))
    return np.linspace(0, len(change), n_seg + 1).astype(int)


def change_offset(
    t_motion_ns: np.ndarray,
    motion: np.ndarray,
    t_force_ns: np.ndarray,
    forces: np.ndarray,
    frame_period_s: float,
    max_lag_s: float = 0.25,
    grid_s: float = 0.001,
    segment_s: float = 1.0,
    n_boot: int = 1000,
    seed: int = 0,
) -> OffsetEstimate:
    """Offset (s) by which motion follows force change, with a bootstrap over events."""
    t0 = max(t_motion_ns[0], t_force_ns[0])
    t1 = min(t_motion_ns[-1], t_force_ns[-1])
    lag = int(round(max_lag_s / grid_s))
    grid = np.arange(0.0, (t1 - t0) / 1e9, grid_s)
    if len(grid) < 4 * lag:
        raise SessionError(
            "the camera and force records overlap for only "
            f"{(t1 - t0) / 1e9:.2f} s; need at least {4 * max_lag_s:.1f} s"
        )
    tm = (t_motion_ns - t0) / 1e9
    m = np.interp(grid, tm, motion)
    right = np.clip(np.searchsorted(tm, grid), 1, len(tm) - 1)
    nearest = np.minimum(np.abs(grid - tm[right - 1]), np.abs(tm[right] - grid))
    covered = nearest <= frame_period_s  # grid points inside a frame gap carry no motion data
    half = frame_period_s / 2
    tf = (t_force_ns - t0) / 1e9
    width = max(1, int(round(frame_period_s / grid_s)))
    box = np.ones(width) / width
    wide = np.arange(-half, grid[-1] + half + grid_s, grid_s)  # the grid plus half a period
    shift = int(round(half / grid_s))
    change = []
    for f in np.atleast_2d(forces.T):
        smooth = np.convolve(np.interp(wide, tf, f), box, "same")  # symmetric: no lag added
        change.append(smooth[2 * shift : 2 * shift + len(grid)] - smooth[: len(grid)])
    g = np.linalg.norm(np.stack(change, axis=1), axis=1)
    bounds = _event_bounds(g[lag : len(g) - lag], grid_s, segment_s)
    m, g = [(x - x.mean()) / (x.std() or 1.0) for x in (m, g)]
    m[~covered] = 0.0
    centre = m[lag : len(m) - lag]
    events = np.array(
        [
            np.correlate(g[a : b + 2 * lag], centre[a:b], "valid")
            for a, b in zip(bounds[:-1], bounds[1:], strict=False)
        ]
    )
    total = events.sum(axis=0)
    lags_s = (lag - np.arange(2 * lag + 1)) * grid_s  # c[k] pairs m(t) with g(t - lag_k)
    to_offset = lambda k: (lag - k) * grid_s  # noqa: E731 - index → seconds
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(events), size=(n_boot, len(events)))
    boot = np.array([to_offset(_peak(events[p].sum(axis=0))) for p in picks])
    floor = grid_s / 2  # resolution of the grid: the bootstrap cannot see below it
    return OffsetEstimate(
        offset_s=to_offset(_peak(total)),
        std_s=float(np.hypot(boot.std(), grid_s / np.sqrt(12))),
        ci95_s=(float(np.percentile(boot, 2.5)) - floor, float(np.percentile(boot, 97.5)) + floor),
        method="change correlation",
        lags_s=lags_s,
        correlation=total / len(centre),
    )
