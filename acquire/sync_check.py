"""``verify_sync``: measure the offset between image motion and force in a session, audit drops,
judge against limits.

Two measurements of the same offset (:func:`measure_offset` picks one):
:mod:`~vbfe.acquire.sync_corners` aligns the kinks the image and the force share where a pull
starts or stops (sharp, sub-frame, the traction protocol's case); :mod:`~vbfe.acquire.sync_changes`
cross-correlates change signals (any profile with distinct force-change events).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vbfe.acquire.audit import StreamAudit, audit_sequence
from vbfe.acquire.errors import SessionError
from vbfe.acquire.reader import FRAME_CORRECTION_ATTR, SessionReader, store_analysis
from vbfe.acquire.record_settings import record_settings
from vbfe.acquire.sync_changes import change_offset, motion_energy
from vbfe.acquire.sync_corners import OffsetEstimate, corner_offset, frame_components


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
        table = record_settings(config)
        return cls(table.sync_max_offset_s, table.sync_max_ci_halfwidth_s,
                   table.sync_max_frame_drop, table.sync_max_force_drop)


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
                 f" (95% CI {1e3 * e.ci95_s[0]:+.2f} … {1e3 * e.ci95_s[1]:+.2f} ms, "
                 f"{e.method})",
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
                "sync_residual_offset_s": self.residual_offset_s, "sync_method": e.method,
                "sync_verdict": "pass" if self.passed else "fail",
                "sync_reasons": json.dumps(self.reasons),
                "sync_drift_ppm": json.dumps(self.drift_ppm),
                "sync_frame_drop_fraction": self.audits["camera"].drop_fraction,
                "sync_force_drop_fraction": self.audits["force"].drop_fraction,
                "sync_limits": json.dumps(self.limits.__dict__),
                FRAME_CORRECTION_ATTR: int(round(self.correction_s * 1e9))}


def _plot(path: Path, report: SyncReport) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    e = report.estimate
    fig, ax = plt.subplots(figsize=(7, 3.5))
    if e.method == "force corners":
        ax.errorbar(e.corner_times_s, e.corner_lags_s * 1e3, yerr=1.96e3 * e.corner_std_s,
                    fmt="o", color="tab:blue", capsize=3, label="lag at each force corner (95%)")
        ax.axhline(e.offset_s * 1e3, color="tab:red", label=f"offset {e.offset_s * 1e3:+.2f} ms")
        ax.axhspan(e.ci95_s[0] * 1e3, e.ci95_s[1] * 1e3, color="tab:red", alpha=0.2,
                   label="95% CI")
        ax.set_xlabel("time in the session (s)")
        ax.set_ylabel("image time - force time (ms)")
    else:
        ax.plot(e.lags_s * 1e3, e.correlation, color="tab:blue", label="correlation")
        ax.axvline(e.offset_s * 1e3, color="tab:red", label=f"offset {e.offset_s * 1e3:+.2f} ms")
        ax.axvspan(e.ci95_s[0] * 1e3, e.ci95_s[1] * 1e3, color="tab:red", alpha=0.2,
                   label="95% CI")
        ax.set_xlabel("image time - force time (ms)")
        ax.set_ylabel("normalized cross-correlation")
    ax.set_title(f"{report.path.name}: {'PASS' if report.passed else 'FAIL'}")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def measure_offset(reader: SessionReader, max_lag_s: float = 0.25) -> OffsetEstimate:
    """The offset from the force corners when they pin it to within a frame period (95%
    interval), else the better determined of the corner and the change-correlation measurement."""
    t_force, forces = reader.force_times_ns(), reader.forces_n()
    t_frames = reader.frame_times_ns()
    found, errors = [], []
    try:
        found.append(corner_offset(t_frames, frame_components(reader), t_force, forces,
                                   max_lag_s=max_lag_s))
    except SessionError as err:
        errors.append(str(err))
    period_s = float(np.median(np.diff(t_frames))) / 1e9
    try:
        t_motion, motion = motion_energy(reader)
        found.append(change_offset(t_motion, motion, t_force, forces, period_s,
                                   max_lag_s=max_lag_s))
    except SessionError as err:
        errors.append(str(err))
    if not found:
        raise SessionError(f"{reader.path}: cannot measure the image-force offset: "
                           + "; ".join(errors))
    corners = [e for e in found if e.method == "force corners"]
    if corners and corners[0].ci95_s[1] - corners[0].ci95_s[0] <= 2 * period_s:
        return corners[0]  # sub-frame alignment on the force's kinks: the sharper measurement
    return min(found, key=lambda e: e.ci95_s[1] - e.ci95_s[0])


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
        estimate = measure_offset(reader, max_lag_s)
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
                       f"{1e3 * limits.max_ci_halfwidth_s:g} ms (too little motion, or too few "
                       "sharp force changes, to align on?)")
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
