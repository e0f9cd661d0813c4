"""Image-vs-force offset from one continuous-time model of the whole session.

The force is first cleaned of its noise without blunting its corners: a least-squares cubic
spline through every sample, knots every ``_KNOT_S`` and a triple knot (slope free to jump) at
each corner of the force (:func:`~vbfe.acquire.sync.corners.force_corners`, placed by the
corner fit). The tissue is a standard linear solid: its displacement follows the force through
``u ∝ F + β·L``, where ``L`` is the force passed through a first-order lag of time constant
``τ`` (the creep under a held force, the relaxation of a still grasp). What the images show is
a smooth function of ``u``: each image component is fitted by a cubic spline in ``u`` evaluated
at the frame's time minus the offset ``δ`` (the force averaged over the exposure, centred on the
frame's time and shifted by the rolling shutter's delay at the rows where the motion is). For
each ``(δ, β, τ)`` the spline's coefficients are linear least squares; ``δ``, ``β`` and ``τ``
minimise ``Σ_c n·log RSS_c`` over the image components, ``δ`` refined by a parabola. Every
pull, hold and release of the session counts, not only the force's corners.

Uncertainty: a moving-block bootstrap of the residuals (blocks of ``_BLOCK_S``, the same rows
for every component) refitted for ``δ``, widened by what the corners' own placement errors
move ``δ`` by; the 95% interval is the bootstrap's percentiles.
"""

from __future__ import annotations

import numpy as np

from vbfe.acquire.sync.corners import (
    Corner,
    OffsetEstimate,
    _box,
    _spline_designs,
    _vertex,
    force_axis,
    force_corners,
)
from vbfe.common.errors import SessionError

_GRID_S = 0.001  # the force is resampled on this grid
_KNOT_S = 0.4  # knot spacing of the force's spline between corners (0.2 s: narrower intervals
# on 15 s freehand trials, but a 6 s trial of the quick demo erred -2.9 ms outside its interval)
_CORNER_CLEARANCE_S = 0.03  # regular knots this close to a corner are left out
_CORNER_WINDOW_S = 0.4  # force samples within this of a corner place it
_CORNER_SEARCH_S = 0.04  # and searched this far around where it was detected
_CORNER_STEP_S = 0.001
_BETAS = (0.25, 1.0)  # weight of the lagged force in the displacement: starting points
_TAUS_S = (0.5, 2.0, 6.0)  # lag time constants: starting points
_COARSE_S = 0.002  # the offset is first searched on this grid
_SHAPE_KNOTS = 8  # interior knots of the image components' spline in u
_BLOCK_S = 1.5  # bootstrap block length
_N_BOOT = 150
_N_FORCE_BOOT = 20  # refits on resampled force noise (each cleans the force again)
_FORCE_BLOCK_S = 0.05  # block length of the force's resampled noise
_REFINE_S = 0.03  # bootstrap refits search this far around the best offset
_BOOT_BETAS = (0.0, 0.5, 2.0)  # the tissue lags the image bootstrap refits besides the best
_BOOT_TAUS_S = (0.5, 3.0, 20.0)
_MIN_FRAMES = 20
METHOD = "viscoelastic model"
MIN_CORNERS = 5  # freehand seed 118 (5 corners): +1.5 ms ± 2.7 by the model, −9 ± 46 by corners
FRAMES_PER_COEFFICIENT = 5  # fewer frames than this per shape coefficient: too few to fit
# the shape and the offset apart (6 s freehand trials at 10 fps, 70 frames, still fit)


def clean_force(t_s: np.ndarray, force: np.ndarray, grid_s: np.ndarray) -> np.ndarray:
    """The force on ``grid_s``: a least-squares cubic spline with knots every ``_KNOT_S`` and
    a triple knot at each of its corners, so noise is averaged out and corners stay sharp."""
    from scipy.interpolate import make_lsq_spline

    corners = _corner_times(t_s, force)
    lo, hi = float(t_s[0]), float(t_s[-1])
    regular = np.arange(lo + _KNOT_S, hi - _KNOT_S / 2, _KNOT_S)
    corners = [c for c in corners if lo + _KNOT_S < c < hi - _KNOT_S]
    if corners:
        gap = np.min(np.abs(regular[:, None] - np.array(corners)[None, :]), axis=1)
        regular = regular[gap > _CORNER_CLEARANCE_S]
    inner = np.sort(np.concatenate([regular, np.repeat(corners, 3)]))
    knots = np.concatenate([[lo] * 4, inner, [hi] * 4])
    spline = make_lsq_spline(t_s, force, knots, k=3)
    return spline(np.clip(grid_s, lo, hi))


def _place_corner(t_s: np.ndarray, force: np.ndarray, corner: Corner) -> float:
    """The knot of the one-knot quadratic spline (flat on the corner's flat side) that best
    fits the raw force samples around a detected corner."""
    near = np.abs(t_s - corner.time_s) <= _CORNER_WINDOW_S
    knots = corner.time_s + np.arange(-_CORNER_SEARCH_S, _CORNER_SEARCH_S + 1e-9, _CORNER_STEP_S)
    design = _spline_designs(t_s[near], knots, _CORNER_WINDOW_S, corner.flat)
    q, _ = np.linalg.qr(design)
    explained = np.sum((q.transpose(0, 2, 1) @ force[near]) ** 2, axis=1)
    k = int(np.argmax(explained))
    return float(knots[0] + _vertex(-explained, k) * _CORNER_STEP_S)


def _corner_times(t_s: np.ndarray, force: np.ndarray) -> list[float]:
    """The force's corners, each placed by a one-knot spline fit on the raw samples."""
    step = float(np.median(np.diff(t_s)))
    smooth = _box(force, max(1, int(round(0.01 / step))))
    return [_place_corner(t_s, force, c) for c in force_corners(t_s, smooth)]


def model_applies(t_force_ns: np.ndarray, forces: np.ndarray, n_frames: int) -> bool:
    """Whether the force turns often enough (at least ``MIN_CORNERS`` corners: pulls, holds,
    releases) for the model to tell the tissue's lag from the offset — a single pull and hold
    does not: its creep fits many lags, each with its own offset — and there are enough frames
    for the shape's coefficients."""
    if n_frames < FRAMES_PER_COEFFICIENT * (_SHAPE_KNOTS + 4) or len(t_force_ns) <= 10:
        return False
    t_s = (t_force_ns - t_force_ns[0]) / 1e9
    return len(_corner_times(t_s, force_axis(forces))) >= MIN_CORNERS


def _lag(force: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order lag (unit gain) of the force on the grid, starting at rest."""
    from scipy.signal import lfilter  # here: scipy.signal costs every vbfe command ~0.8 s

    alpha = 1.0 - np.exp(-_GRID_S / tau_s)
    out, _ = lfilter([alpha], [1.0, alpha - 1.0], force, zi=[(1.0 - alpha) * force[0]])
    return out


def _shape_design(u: np.ndarray, lo: float, hi: float, knots: int = _SHAPE_KNOTS) -> np.ndarray:
    """Uniform cubic B-spline basis (… × basis functions) in ``u`` over ``[lo, hi]``, with
    ``knots`` interior knots."""
    intervals = knots + 1
    s = np.clip((u - lo) / ((hi - lo) or 1.0), 0.0, 1.0) * intervals
    i = np.minimum(s.astype(int), intervals - 1)
    f = s - i
    weights = (
        np.stack(
            [(1 - f) ** 3, 3 * f**3 - 6 * f**2 + 4, -3 * f**3 + 3 * f**2 + 3 * f + 1, f**3], axis=-1
        )
        / 6.0
    )
    out = np.zeros((*u.shape, intervals + 3))
    columns = i[..., None] + np.arange(4)
    np.put_along_axis(out, columns, weights, axis=-1)
    return out


def _deviance(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``Σ_c n·log RSS_c`` of least squares of ``y`` (n × c) on each design ``x`` (g × n × p)."""
    q, _ = np.linalg.qr(x)
    rss = np.sum(y**2, axis=0) - np.sum((q.transpose(0, 2, 1) @ y) ** 2, axis=1)
    return len(y) * np.sum(np.log(np.maximum(rss, 1e-300)), axis=1)


def _design(
    u: np.ndarray, t_s: np.ndarray, lags_s: np.ndarray, knots: int = _SHAPE_KNOTS
) -> np.ndarray:
    """The shape spline of ``u`` (grid) at the frame times minus each lag (lags × n × p)."""
    index = np.rint((t_s[None, :] - lags_s[:, None]) / _GRID_S).astype(int)
    return _shape_design(u[index], float(u.min()), float(u.max()), knots)


def _best(deviance: np.ndarray, lags_s: np.ndarray) -> float:
    k = int(np.argmin(deviance))
    return float(lags_s[0] + _vertex(deviance, k) * (lags_s[1] - lags_s[0]))


def model_offset(
    t_frames_ns: np.ndarray,
    components: np.ndarray,
    t_force_ns: np.ndarray,
    forces: np.ndarray,
    exposure_s: float = 0.0,
    row_delay_s: float = 0.0,
    max_lag_s: float = 0.25,
    n_boot: int = _N_BOOT,
    n_force_boot: int = _N_FORCE_BOOT,
    seed: int = 0,
) -> OffsetEstimate:
    """Lag (s) by which the image ``components`` (stamped ``t_frames_ns``, the exposure's
    centre) follow the force, with a block-bootstrap 95% interval. ``row_delay_s``: how much
    later than the frame's time the rows where the motion is were exposed.

    Raises :class:`SessionError` when too few frames overlap the force record.
    """
    t0 = int(t_force_ns[0])
    t_force = (t_force_ns - t0) / 1e9
    grid = np.arange(0.0, t_force[-1], _GRID_S)
    axis = force_axis(forces)
    cleaned = clean_force(t_force, axis, grid)
    scale = float(np.abs(cleaned).max()) or 1.0

    def exposed(force: np.ndarray) -> np.ndarray:
        if exposure_s > _GRID_S:
            force = _box(force, int(round(exposure_s / _GRID_S)))
        return force / scale

    force = exposed(cleaned)
    t, y = _frames_in_record((t_frames_ns - t0) / 1e9 + row_delay_s, components, grid, max_lag_s)
    coarse = np.arange(-max_lag_s, max_lag_s + _COARSE_S / 2, _COARSE_S)
    lags = np.arange(-max_lag_s, max_lag_s + _GRID_S / 2, _GRID_S)

    def displacement(params: np.ndarray, force: np.ndarray = force) -> np.ndarray:
        beta, log_tau = params
        return force + abs(beta) * _lag(force, float(np.exp(np.clip(log_tau, -3.0, 4.0))))

    from scipy.optimize import minimize

    def worst(params: np.ndarray) -> float:
        return float(_deviance(_design(displacement(params), t, coarse), y).min())

    starts = [np.array([b, np.log(tau)]) for b in _BETAS for tau in _TAUS_S]
    start = min(starts, key=worst)
    fit = minimize(worst, start, method="Nelder-Mead", options={"xatol": 0.01, "fatol": 0.1})
    u = displacement(fit.x)
    rough = float(coarse[int(np.argmin(_deviance(_design(u, t, coarse), y)))])
    lags = lags[np.abs(lags - rough) <= 5 * _COARSE_S]
    profile = _deviance(_design(u, t, lags), y)
    offset = _best(profile, lags)
    x = _design(u, t, np.array([offset]))[0]
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    fitted = x @ coef
    residual = y - fitted

    # the image's misfit: its residuals resampled in blocks, refitted for the offset and the
    # tissue's lag (designs for every lag near the offset and every (β, τ) of a wide grid,
    # orthonormalised once)
    near = np.arange(offset - _REFINE_S, offset + _REFINE_S + _GRID_S / 2, _GRID_S)
    near = near[np.abs(near) <= max_lag_s]
    tissue = [fit.x] + [np.array([b, np.log(tau)]) for b in _BOOT_BETAS for tau in _BOOT_TAUS_S]
    qt = np.stack([np.linalg.qr(_design(displacement(p), t, near))[0] for p in tissue])
    qt = qt.transpose(0, 1, 3, 2).copy()  # tissue × lag × p × n
    n = len(t)
    rng = np.random.default_rng(seed)
    rows = _block_rows(rng, n, max(2, int(round(_BLOCK_S / float(np.median(np.diff(t)))))), n_boot)
    image_boot = []
    for r in rows:
        yb = fitted + residual[r]
        explained = np.sum((qt @ yb) ** 2, axis=2)
        rss = np.sum(yb**2, axis=0) - explained
        dev = n * np.sum(np.log(np.maximum(rss, 1e-300)), axis=2)  # tissue × lag
        image_boot.append(_best(dev[int(np.argmin(dev.min(axis=1)))], near))

    # the force's noise, and where it puts the corners: the cleaned force plus its residuals
    # resampled in blocks, cleaned again and refitted (the tissue's lag held)
    smooth = np.interp(t_force, grid, cleaned)
    noise = axis - smooth
    block = max(2, int(round(_FORCE_BLOCK_S / float(np.median(np.diff(t_force))))))
    force_boot = []
    for pick in _block_rows(rng, len(noise), block, n_force_boot):
        again = exposed(clean_force(t_force, smooth + noise[pick], grid))
        force_boot.append(_best(_deviance(_design(displacement(fit.x, again), t, near), y), near))
    return _estimate(offset, image_boot, force_boot, rng, METHOD, lags, profile, n)


def _frames_in_record(
    t_frames_s: np.ndarray, components: np.ndarray, grid_s: np.ndarray, max_lag_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """The frame times (s) whose every lag stays inside the force record ``grid_s`` and their
    components scaled to unit spread; SessionError when too few."""
    inside = (t_frames_s - max_lag_s >= 0) & (t_frames_s + max_lag_s <= grid_s[-1])
    if inside.sum() < _MIN_FRAMES:
        raise SessionError(
            f"only {int(inside.sum())} frames lie inside the force record (need {_MIN_FRAMES})"
        )
    y = components[inside]
    return t_frames_s[inside], y / (y.std(axis=0) + 1e-12)


def _estimate(
    offset_s: float,
    image_boot: list[float],
    force_boot: list[float],
    rng: np.random.Generator,
    method: str,
    lags_s: np.ndarray,
    deviance: np.ndarray,
    n_frames: int,
) -> OffsetEstimate:
    """The offset with its spread and 95% interval from the image's bootstrap offsets plus the
    force's (centred, paired at random), widened by the lag grid's resolution."""
    both = np.array(image_boot) + rng.permutation(
        np.resize(np.array(force_boot) - np.mean(force_boot), len(image_boot))
    )
    low, high = np.percentile(both, [2.5, 97.5])
    floor = _GRID_S / 2  # the grid's resolution: the bootstrap cannot see below it
    return OffsetEstimate(
        offset_s=offset_s,
        std_s=float(np.hypot(both.std(), _GRID_S / np.sqrt(12))),
        ci95_s=(float(min(low, offset_s)) - floor, float(max(high, offset_s)) + floor),
        method=method,
        lags_s=lags_s,
        correlation=-(deviance - deviance.min()) / n_frames,
    )


def _block_rows(rng: np.random.Generator, n: int, block: int, draws: int) -> np.ndarray:
    """Row indices (draws × n) of moving-block bootstrap samples of ``n`` rows."""
    block = min(block, n)
    starts = rng.integers(0, n - block + 1, size=(draws, -(-n // block)))
    return (starts[:, :, None] + np.arange(block)).reshape(draws, -1)[:, :n]
