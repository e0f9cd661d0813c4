"""``verify_sync``: measure the offset between image motion and force change in a session.

Both streams are mapped onto the host clock (clock fits), turned into "how much is changing"
signals — mean absolute difference of consecutive (downscaled, grey) left frames, and the norm
of the force change over one frame period centred on the same instant — resampled onto a 1 ms
grid and cross-correlated. The peak, refined by a parabola through its neighbours, is the
offset (positive: images are stamped later than the forces of the same instant). A bootstrap
over time segments gives its uncertainty and 95% confidence interval.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.signal import find_peaks

from vbfe.acquire.audit import StreamAudit, audit_sequence
from vbfe.acquire.errors import SessionError
from vbfe.acquire.reader import FRAME_CORRECTION_ATTR, SessionReader, store_analysis

_MOTION_WIDTH = 160  # frames are downscaled to this width before differencing
_EVENT_FRACTION = 0.25  # a segment is an event when its force change is this share of the most
_MIN_EVENTS = 3  # fewer force-change events than this: bootstrap over fixed segments
_EVENT_SPACING_S = 0.3
_MAX_STEP_PERIODS = 1.5  # frame pairs further apart than this (in periods) straddle a drop


@dataclass(frozen=True)
class SyncLimits:
    """Pass/fail limits of :func:`verify_sync` (the ``sync_*`` keys of the ``[record]`` table)."""

    max_offset_s: float = 0.003
    max_ci_halfwidth_s: float = 0.005  # the offset must be known at least this well
    max_frame_drop: float = 0.05
    max_force_drop: float = 0.05

    @classmethod
    def from_config(cls, config: dict[str, dict[str, Any]]) -> "SyncLimits":
        """Limits from a rig configuration's ``[record]`` table."""
        table = config.get("record", {})
        default = cls()
        return cls(float(table.get("sync_max_offset_s", default.max_offset_s)),
                   float(table.get("sync_max_ci_halfwidth_s", default.max_ci_halfwidth_s)),
                   float(table.get("sync_max_frame_drop", default.max_frame_drop)),
                   float(table.get("sync_max_force_drop", default.max_force_drop)))


@dataclass
class OffsetEstimate:
    """Result of the cross-correlation of two change signals."""

    offset_s: float
    std_s: float
    ci95_s: tuple[float, float]
    peak_correlation: float
    lags_s: np.ndarray
    correlation: np.ndarray


@dataclass
class SyncReport:
    """Offset, its uncertainty, clock drifts, drop audit and the verdict of one session."""

    path: Path
    estimate: OffsetEstimate
    correction_s: float  # frame-time correction in force after this check (0 if none)
    residual_offset_s: float  # offset left once that correction is applied
    drift_ppm: dict[str, float]
    drift_uncertainty_ppm: dict[str, float]
    jitter_s: dict[str, float]
    audits: dict[str, StreamAudit]
    limits: SyncLimits
    passed: bool
    reasons: list[str] = field(default_factory=list)
    plot_path: Path | None = None

    def text(self) -> str:
        """Human-readable report."""
        e = self.estimate
        lines = [f"session    {self.path}",
                 f"offset     image - force = {1e3 * e.offset_s:+.2f} ms ± {1e3 * e.std_s:.2f} ms"
                 f" (95% CI {1e3 * e.ci95_s[0]:+.2f} … {1e3 * e.ci95_s[1]:+.2f} ms, peak "
                 f"correlation {e.peak_correlation:.2f})",
                 f"correction {1e3 * self.correction_s:+.2f} ms applied to frame times; residual "
                 f"{1e3 * self.residual_offset_s:+.2f} ms"]
        for stream, ppm in self.drift_ppm.items():
            lines.append(f"clock      {stream}: drift {ppm:+.1f} ± "
                         f"{self.drift_uncertainty_ppm[stream]:.1f} ppm vs host, jitter "
                         f"{1e3 * self.jitter_s[stream]:.3f} ms")
        for stream, au in self.audits.items():
            lines.append(f"audit      {stream}: {au.stored} stored, {au.dropped} dropped "
                         f"({100 * au.drop_fraction:.2f}%), {au.duplicated} duplicated, "
                         f"{au.reordered} out of order")
        lines.append("verdict    " + ("PASS" if self.passed else "FAIL: " + "; ".join(self.reasons)))
        if self.plot_path is not None:
            lines.append(f"plot       {self.plot_path}")
        return "\n".join(lines)

    def to_attrs(self) -> dict[str, Any]:
        """What is stored in the session's ``/analysis`` attributes."""
        e = self.estimate
        return {"sync_offset_s": e.offset_s, "sync_offset_std_s": e.std_s,
                "sync_offset_ci95_low_s": e.ci95_s[0], "sync_offset_ci95_high_s": e.ci95_s[1],
                "sync_residual_offset_s": self.residual_offset_s,
                "sync_verdict": "pass" if self.passed else "fail",
                "sync_reasons": json.dumps(self.reasons),
                "sync_drift_ppm": json.dumps(self.drift_ppm),
                "sync_frame_drop_fraction": self.audits["camera"].drop_fraction,
                "sync_force_drop_fraction": self.audits["force"].drop_fraction,
                "sync_limits": json.dumps(self.limits.__dict__),
                FRAME_CORRECTION_ATTR: int(round(self.correction_s * 1e9))}


def motion_energy(reader: SessionReader) -> tuple[np.ndarray, np.ndarray]:
    """Mean |difference| of consecutive left frames, at the midpoints of their host times."""
    times = reader.frame_times_ns()
    previous = None
    energy = np.zeros(max(reader.n_frames - 1, 0))
    for i, frame in enumerate(reader.iter_frames()):
        grey = cv2.cvtColor(frame.left, cv2.COLOR_BGR2GRAY)
        scale = min(1.0, _MOTION_WIDTH / grey.shape[1])
        if scale < 1.0:
            grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        grey = grey.astype(np.float32)
        if previous is not None:
            energy[i - 1] = float(np.mean(np.abs(grey - previous)))
        previous = grey
    step = np.diff(times)
    consecutive = step <= _MAX_STEP_PERIODS * np.median(step)  # not across dropped frames
    return ((times[:-1] + times[1:]) // 2)[consecutive], energy[consecutive]


def _peak(correlation: np.ndarray) -> float:
    """Index of the maximum, refined by a parabola through it and its neighbours."""
    k = int(np.argmax(correlation))
    if 0 < k < len(correlation) - 1:
        ym, y0, yp = correlation[k - 1:k + 2]
        denom = ym - 2 * y0 + yp
        if denom < 0:
            return k + 0.5 * (ym - yp) / denom
    return float(k)


def _event_bounds(change: np.ndarray, grid_s: float, segment_s: float) -> np.ndarray:
    """Cut points splitting the record into one segment per force-change event (cut at the
    quietest instant between events), or into ``segment_s`` pieces when there are few events."""
    peaks, _ = find_peaks(change, prominence=_EVENT_FRACTION * float(change.max() or 1.0),
                          distance=max(1, int(_EVENT_SPACING_S / grid_s)))
    if len(peaks) >= _MIN_EVENTS:
        cuts = [a + int(np.argmin(change[a:b])) for a, b in zip(peaks[:-1], peaks[1:])]
        return np.array([0, *cuts, len(change)])
    n_seg = max(2, int(len(change) * grid_s / segment_s))
    return np.linspace(0, len(change), n_seg + 1).astype(int)


def estimate_offset(t_motion_ns: np.ndarray, motion: np.ndarray, t_force_ns: np.ndarray,
                    forces: np.ndarray, frame_period_s: float, max_lag_s: float = 0.25,
                    grid_s: float = 0.001, segment_s: float = 1.0, n_boot: int = 1000,
                    seed: int = 0) -> OffsetEstimate:
    """Offset (s) by which motion follows force change, with a bootstrap over events."""
    t0 = max(t_motion_ns[0], t_force_ns[0])
    t1 = min(t_motion_ns[-1], t_force_ns[-1])
    lag = int(round(max_lag_s / grid_s))
    grid = np.arange(0.0, (t1 - t0) / 1e9, grid_s)
    if len(grid) < 4 * lag:
        raise SessionError("the camera and force records overlap for only "
                           f"{(t1 - t0) / 1e9:.2f} s; need at least {4 * max_lag_s:.1f} s")
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
        change.append(smooth[2 * shift:2 * shift + len(grid)] - smooth[:len(grid)])
    g = np.linalg.norm(np.stack(change, axis=1), axis=1)
    bounds = _event_bounds(g[lag:len(g) - lag], grid_s, segment_s)
    m, g = [(x - x.mean()) / (x.std() or 1.0) for x in (m, g)]
    m[~covered] = 0.0
    centre = m[lag:len(m) - lag]
    events = np.array([np.correlate(g[a:b + 2 * lag], centre[a:b], "valid")
                       for a, b in zip(bounds[:-1], bounds[1:])])
    total = events.sum(axis=0)
    lags_s = (lag - np.arange(2 * lag + 1)) * grid_s  # c[k] pairs m(t) with g(t - lag_k)
    to_offset = lambda k: (lag - k) * grid_s  # noqa: E731 - index → seconds
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(events), size=(n_boot, len(events)))
    boot = np.array([to_offset(_peak(events[p].sum(axis=0))) for p in picks])
    floor = grid_s / 2  # resolution of the grid: the bootstrap cannot see below it
    return OffsetEstimate(offset_s=to_offset(_peak(total)),
                          std_s=float(np.hypot(boot.std(), grid_s / np.sqrt(12))),
                          ci95_s=(float(np.percentile(boot, 2.5)) - floor,
                                  float(np.percentile(boot, 97.5)) + floor),
                          peak_correlation=float(total.max() / len(centre)), lags_s=lags_s,
                          correlation=total / len(centre))


def _plot(path: Path, report: SyncReport) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    e = report.estimate
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(e.lags_s * 1e3, e.correlation, color="tab:blue", label="correlation")
    ax.axvline(e.offset_s * 1e3, color="tab:red", label=f"offset {e.offset_s * 1e3:+.2f} ms")
    ax.axvspan(e.ci95_s[0] * 1e3, e.ci95_s[1] * 1e3, color="tab:red", alpha=0.2, label="95% CI")
    ax.set_xlabel("image time - force time (ms)")
    ax.set_ylabel("normalized cross-correlation")
    ax.set_title(f"{report.path.name}: {'PASS' if report.passed else 'FAIL'}")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def verify_sync(path: str | Path, limits: SyncLimits | None = None,
                plot_path: str | Path | None = None, store: bool = True,
                apply_correction: bool = False, max_lag_s: float = 0.25) -> SyncReport:
    """Measure the image-force offset of a session, audit drops, judge against ``limits``.

    With ``store`` the numbers and verdict go into the session's ``/analysis`` attributes; with
    ``apply_correction`` the measured offset is also stored as a frame-time correction, which
    :class:`SessionReader` applies from then on.
    """
    limits = limits or SyncLimits()
    with SessionReader(path) as reader:
        if reader.n_frames < 3 or len(reader.forces_n()) < 3:
            raise SessionError(f"{path} has too few frames or force samples to check sync")
        t_motion, motion = motion_energy(reader)
        frame_period_s = float(np.median(np.diff(reader.frame_times_ns()))) / 1e9
        estimate = estimate_offset(t_motion, motion, reader.force_times_ns(), reader.forces_n(),
                                   frame_period_s, max_lag_s=max_lag_s)
        previous = int(reader.analysis().get(FRAME_CORRECTION_ATTR, 0)) / 1e9
        fits = {s: reader.clock_fit(s) for s in ("camera", "force")}
        audits = {s: audit_sequence(reader.stream_times(s)[2]) for s in ("camera", "force")}
    applied = estimate.offset_s if apply_correction else 0.0
    residual = estimate.offset_s - applied
    half_ci = (estimate.ci95_s[1] - estimate.ci95_s[0]) / 2
    reasons = []
    if abs(residual) > limits.max_offset_s:
        reasons.append(f"offset {1e3 * residual:+.2f} ms exceeds ±{1e3 * limits.max_offset_s:g} ms")
    if half_ci > limits.max_ci_halfwidth_s:
        reasons.append(f"offset uncertain: 95% CI half-width {1e3 * half_ci:.2f} ms exceeds "
                       f"{1e3 * limits.max_ci_halfwidth_s:g} ms (too little motion?)")
    for stream, limit in (("camera", limits.max_frame_drop), ("force", limits.max_force_drop)):
        if audits[stream].drop_fraction > limit:
            reasons.append(f"{stream} dropped {100 * audits[stream].drop_fraction:.1f}% "
                           f"(limit {100 * limit:g}%)")
    report = SyncReport(path=Path(path), estimate=estimate, correction_s=previous + applied,
                        residual_offset_s=residual,
                        drift_ppm={s: f.drift_ppm for s, f in fits.items()},
                        drift_uncertainty_ppm={s: f.drift_uncertainty_ppm for s, f in fits.items()},
                        jitter_s={s: f.jitter_ns / 1e9 for s, f in fits.items()},
                        audits=audits, limits=limits, passed=not reasons, reasons=reasons,
                        plot_path=Path(plot_path) if plot_path else None)
    if report.plot_path is not None:
        _plot(report.plot_path, report)
    if store:
        store_analysis(path, report.to_attrs())
    return report
