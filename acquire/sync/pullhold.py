"""Image-vs-force offset of a pull-hold session from one fit of each whole record.

The paper's protocol pulls at a constant speed from rest until the target force, then holds the
force. The tissue is a standard linear solid, so the force has the protocol's own shape: flat at
rest, the ramp ``F0 + a·s + b·τ·(1 − e^{−s/τ})`` from the onset (``s`` = time since the onset)
to the hold, then flat. It is fitted to every force sample (six parameters, least squares). The
same solid fixes the grasp's displacement up to its scale: ``s`` during the pull, then the
creep ``T + (b/a)·τ·(1 − e^{−T/τ})·(1 − e^{−h/τc})`` under the held force (``T`` the pull's
length, ``h`` the time since the hold began, ``τc = τ·(1 + b/a)``). What the images show is a
smooth function of that displacement: each image component is fitted by a cubic spline in it,
evaluated at the frame's time (exposure centre, displacement averaged over the exposure) minus
the offset ``δ``; ``δ`` minimises ``Σ_c n·log RSS_c`` over every frame of the rest, pull and
hold, refined by a parabola.

Uncertainty: the image residuals resampled in blocks and refitted for ``δ``, plus the force's
residuals resampled in blocks and the force refitted (which moves the onset and hold instants
the displacement is built on); the 95% interval is the percentiles of their sum.
"""

from __future__ import annotations

import numpy as np

from vbfe.acquire.sync.corners import OffsetEstimate, _box, force_axis, force_corners
from vbfe.acquire.sync.viscoelastic import (
    _BLOCK_S,
    _FORCE_BLOCK_S,
    _GRID_S,
    _REFINE_S,
    _best,
    _block_rows,
    _design,
    _deviance,
    _estimate,
    _frames_in_record,
)
from vbfe.common.errors import SessionError

METHOD = "pull-hold fit"
_TAU0_S = 1.5  # starting relaxation time of the force fit
_TAU_RANGE_S = (0.05, 20.0)  # the relaxation time the force fit may take
_N_BOOT = 200
_N_FORCE_BOOT = 40
_SHAPE_KNOTS = 12  # interior knots of the image components' spline in the displacement


def _ramp(t_s: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The protocol's force shape at ``t_s`` for ``p = (F0, onset, hold, a, b, log τ)``."""
    f0, onset, hold, a, b, log_tau = p
    tau = float(np.exp(log_tau))
    s = np.clip(t_s - onset, 0.0, max(hold - onset, 0.0))
    return f0 + a * s + b * tau * (1.0 - np.exp(-s / tau))


def fit_force(t_s: np.ndarray, force: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Least-squares parameters of :func:`_ramp` through every force sample from ``start``.
    The solid's gains keep the sign of the start's ramp (a short, nearly straight pull
    otherwise trades a negative ``a`` against a long ``τ``) and ``τ`` stays within
    ``_TAU_RANGE_S``."""
    from scipy.optimize import least_squares

    sign = 1.0 if start[3] >= 0 else -1.0
    low = np.array([-np.inf, -np.inf, -np.inf, 0.0, 0.0, np.log(_TAU_RANGE_S[0])])
    high = np.array([np.inf, np.inf, np.inf, np.inf, np.inf, np.log(_TAU_RANGE_S[1])])
    flip = np.array([1.0, 1.0, 1.0, sign, sign, 1.0])
    x0 = np.clip(start * flip, low + 1e-9, high - 1e-9)
    fit = least_squares(
        lambda p: _ramp(t_s, p * flip) - force,
        x0,
        bounds=(low, high),
        x_scale=np.array([0.1, 0.01, 0.01, 0.1, 0.1, 0.3]),
        diff_step=1e-6,
    )
    return fit.x * flip


def _start(t_s: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Starting parameters from the force's corners: exactly two, the end of a rest and the
    start of a hold."""
    step = float(np.median(np.diff(t_s)))
    corners = force_corners(t_s, _box(force, max(1, int(round(0.01 / step)))))
    if len(corners) != 2 or corners[0].flat != "before" or corners[-1].flat != "after":
        raise SessionError("the force is not one pull from rest to a hold")
    onset, hold = corners[0].time_s, corners[-1].time_s
    f0 = float(np.median(force[t_s < onset]))
    slope = (float(np.median(force[t_s > hold])) - f0) / (hold - onset)
    return np.array([f0, onset, hold, slope, 0.0, np.log(_TAU0_S)])


def displacement(grid_s: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The grasp's displacement (in units of the pull speed) the force fit ``p`` implies."""
    _, onset, hold, a, b, log_tau = p
    tau = float(np.exp(log_tau))
    ratio = b / a if a else 0.0
    length = max(hold - onset, 0.0)
    creep = ratio * tau * (1.0 - np.exp(-length / tau))
    tau_c = tau * (1.0 + ratio) if 1.0 + ratio > 0 else tau
    held = np.maximum(grid_s - hold, 0.0)
    return np.clip(grid_s - onset, 0.0, length) + creep * (1.0 - np.exp(-held / tau_c))


def pull_hold_offset(
    t_frames_ns: np.ndarray,
    components: np.ndarray,
    t_force_ns: np.ndarray,
    forces: np.ndarray,
    exposure_s: float = 0.0,
    max_lag_s: float = 0.25,
    n_boot: int = _N_BOOT,
    n_force_boot: int = _N_FORCE_BOOT,
    seed: int = 0,
) -> OffsetEstimate:
    """Lag (s) by which the image ``components`` (stamped ``t_frames_ns``, the exposure's
    centre) follow the force of one pull-hold session, with a bootstrap 95% interval.

    Raises :class:`SessionError` when the force is not one pull from rest to a hold or too few
    frames overlap it.
    """
    t0 = int(t_force_ns[0])
    t_force = (t_force_ns - t0) / 1e9
    axis = force_axis(forces)
    params = fit_force(t_force, axis, _start(t_force, axis))
    grid = np.arange(0.0, t_force[-1], _GRID_S)
    box = int(round(exposure_s / _GRID_S))

    def exposed(p: np.ndarray) -> np.ndarray:
        u = displacement(grid, p)
        return _box(u, box) if box > 1 else u

    t, y = _frames_in_record((t_frames_ns - t0) / 1e9, components, grid, max_lag_s)
    u = exposed(params)
    lags = np.arange(-max_lag_s, max_lag_s + _GRID_S / 2, _GRID_S)
    profile = _deviance(_design(u, t, lags, _SHAPE_KNOTS), y)
    offset = _best(profile, lags)
    x = _design(u, t, np.array([offset]), _SHAPE_KNOTS)[0]
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    fitted = x @ coef
    residual = y - fitted

    near = np.arange(offset - _REFINE_S, offset + _REFINE_S + _GRID_S / 2, _GRID_S)
    near = near[np.abs(near) <= max_lag_s]
    qt = np.linalg.qr(_design(u, t, near, _SHAPE_KNOTS))[0].transpose(0, 2, 1).copy()  # lag × p × n
    n = len(t)
    rng = np.random.default_rng(seed)
    rows = _block_rows(rng, n, max(2, int(round(_BLOCK_S / float(np.median(np.diff(t)))))), n_boot)
    image_boot = []
    for r in rows:
        yb = fitted + residual[r]
        rss = np.sum(yb**2, axis=0) - np.sum((qt @ yb) ** 2, axis=1)
        image_boot.append(_best(n * np.sum(np.log(np.maximum(rss, 1e-300)), axis=1), near))

    smooth = _ramp(t_force, params)
    noise = axis - smooth
    block = max(2, int(round(_FORCE_BLOCK_S / float(np.median(np.diff(t_force))))))
    force_boot = []
    for pick in _block_rows(rng, len(noise), block, n_force_boot):
        again = fit_force(t_force, smooth + noise[pick], params)
        force_boot.append(_best(_deviance(_design(exposed(again), t, near, _SHAPE_KNOTS), y), near))
    return _estimate(offset, image_boot, force_boot, rng, METHOD, lags, profile, n)
