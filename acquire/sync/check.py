"""``verify_sync``: measure the offset between image motion and force in a session, audit drops,
judge against limits.

A sync protocol session (``vbfe record --protocol sync``) is measured from its taps and
projector flashes (:mod:`~vbfe.acquire.sync.protocol`) and judged PASS/FAIL. An ordinary traction
session is measured passively (:func:`measure_offset` picks how): a session whose force turns
often (freehand trials: pulls, holds, releases) by one viscoelastic model of the whole session
(:mod:`~vbfe.acquire.sync.viscoelastic`); a single pull and hold, which cannot tell the tissue's
creep from the offset, at the kinks the image and the force share where the pull starts or
stops (:mod:`~vbfe.acquire.sync.corners`) or by cross-correlating change signals
(:mod:`~vbfe.acquire.sync.changes`). A passive verdict is PASS only when the whole 95% interval
lies within the limit, FAIL only when it lies beyond, INCONCLUSIVE otherwise.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vbfe.acquire.recording.settings import RecordSettings
from vbfe.acquire.session.annotate import store_analysis
from vbfe.acquire.session.audit import StreamAudit, audit_sequence
from vbfe.acquire.session.layout import CAMERA, FORCE
from vbfe.acquire.session.reader import FRAME_CORRECTION_ATTR, SessionReader
from vbfe.acquire.sync.changes import change_offset, motion_energy
from vbfe.acquire.sync.corners import (
    OffsetEstimate,
    corner_offset,
    frame_components,
    grasp_components,
)
from vbfe.acquire.sync.protocol import (
    EventEstimate,
    ProtocolResult,
    ProtocolSettings,
    analyse_protocol,
)
from vbfe.acquire.sync.pullhold import METHOD as PULL_HOLD_METHOD
from vbfe.acquire.sync.pullhold import pull_hold_offset
from vbfe.acquire.sync.streams import stream_offset
from vbfe.acquire.sync.viscoelastic import METHOD as MODEL_METHOD
from vbfe.acquire.sync.viscoelastic import model_applies, model_offset
from vbfe.common.errors import SessionError
from vbfe.common.files import save_figure

PASS, FAIL, INCONCLUSIVE = "PASS", "FAIL", "INCONCLUSIVE"
MIN_TAPS = 5  # fewer taps found: a protocol session cannot pass
SYNC_ESTIMATOR = "viscoelastic-2"  # stored with each result: older results are measured again


@dataclass(frozen=True)
class SyncLimits:
    """Pass/fail limits of :func:`verify_sync` (the ``sync_*`` keys of the ``[record]`` table)."""

    max_offset_s: float = 0.003
    max_ci_halfwidth_s: float = 0.005  # the offset must be known at least this well
    max_frame_drop: float = 0.05
    max_force_drop: float = 0.05

    @classmethod
    def from_record(cls, table: RecordSettings) -> SyncLimits:
        """Limits from the ``[record]`` settings."""
        return cls(
            table.sync_max_offset_s,
            table.sync_max_ci_halfwidth_s,
            table.sync_max_frame_drop,
            table.sync_max_force_drop,
        )


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
    verdict: str  # PASS, FAIL or INCONCLUSIVE
    reasons: list[str] = field(default_factory=list)
    plot_path: Path | None = None
    protocol: ProtocolResult | None = None  # a sync protocol session's flashes, taps, drifts
    streams: dict[str, OffsetEstimate | str] = field(default_factory=dict)  # extra stream:
    # its motion's lag behind the force (a third clock), or why it could not be measured

    @property
    def passed(self) -> bool:
        """The verdict is PASS."""
        return self.verdict == PASS

    def config_suggestion(self) -> str:
        """The ``[record]`` line that stores this correction in every new session."""
        return f"frame_time_correction_s = {self.correction_s:.4f}"

    def text(self) -> str:
        """Human-readable report."""
        e = self.estimate
        lines = [
            f"session    {self.path}",
            f"offset     image - force = {1e3 * e.offset_s:+.2f} ms ± {1e3 * e.std_s:.2f} ms"
            f" (95% CI {1e3 * e.ci95_s[0]:+.2f} … {1e3 * e.ci95_s[1]:+.2f} ms, "
            f"{e.method})",
            f"correction {1e3 * self.correction_s:+.2f} ms applied to frame times; residual "
            f"{1e3 * self.residual_offset_s:+.2f} ms",
        ]
        if self.protocol is not None:
            lines += _protocol_lines(self.protocol)
        for name, found in self.streams.items():
            lines.append(
                f"stream     {name} - force = {1e3 * found.offset_s:+.2f} ms ± "
                f"{1e3 * found.std_s:.2f} ms ({found.corners} corners; image - {name} "
                f"= {1e3 * (e.offset_s - found.offset_s):+.2f} ms)"
                if isinstance(found, OffsetEstimate)
                else f"stream     {name}: no clock check ({found})"
            )
        for stream, ppm in self.drift_ppm.items():
            lines.append(
                f"clock      {stream}: drift {ppm:+.1f} ± "
                f"{self.drift_uncertainty_ppm[stream]:.1f} ppm vs host, jitter "
                f"{1e3 * self.jitter_s[stream]:.3f} ms"
            )
        for stream, au in self.audits.items():
            lines.append(
                f"audit      {stream}: {au.stored} stored, {au.dropped} dropped "
                f"({100 * au.drop_fraction:.2f}%), {au.duplicated} duplicated, "
                f"{au.reordered} out of order"
            )
        verdict = self.verdict
        if self.verdict == INCONCLUSIVE:
            verdict += " - record a sync protocol session (vbfe record --protocol sync)"
        lines.append(
            "verdict    "
            + verdict
            + "".join(("; " if i else ": ") + r for i, r in enumerate(self.reasons))
        )
        if self.plot_path is not None:
            lines.append(f"plot       {self.plot_path}")
        return "\n".join(lines)

    def to_attrs(self) -> dict[str, Any]:
        """What is stored in the session's ``/analysis`` attributes."""
        e = self.estimate
        return {
            "sync_offset_s": e.offset_s,
            "sync_offset_std_s": e.std_s,
            "sync_offset_ci95_low_s": e.ci95_s[0],
            "sync_offset_ci95_high_s": e.ci95_s[1],
            "sync_residual_offset_s": self.residual_offset_s,
            "sync_method": e.method,
            "sync_estimator": SYNC_ESTIMATOR,
            "sync_verdict": self.verdict.lower(),
            "sync_protocol": "sync" if self.protocol is not None else "traction",
            "sync_reasons": json.dumps(self.reasons),
            "sync_drift_ppm": json.dumps(self.drift_ppm),
            "sync_frame_drop_fraction": self.audits[CAMERA].drop_fraction,
            "sync_force_drop_fraction": self.audits[FORCE].drop_fraction,
            "sync_limits": json.dumps(self.limits.__dict__),
            FRAME_CORRECTION_ATTR: int(round(self.correction_s * 1e9)),
            "sync_stream_offsets_s": json.dumps(
                {
                    n: [f.offset_s, f.std_s]
                    for n, f in self.streams.items()
                    if isinstance(f, OffsetEstimate)
                }
            ),
            **(_protocol_attrs(self.protocol) if self.protocol is not None else {}),
        }


def _interval(e: EventEstimate) -> str:
    return (
        f"{1e3 * e.value_s:+.2f} ms (95% CI {1e3 * e.ci95_s[0]:+.2f} … "
        f"{1e3 * e.ci95_s[1]:+.2f} ms, {e.n_used} events"
    )


def _protocol_lines(p: ProtocolResult) -> list[str]:
    lines = [
        f"taps       {p.taps_found} found"
        + (f", offset {_interval(p.offset)})" if p.offset else ", none measurable")
    ]
    if p.flash_latency is not None and p.camera_latency_s is not None:
        lines.append(
            f"flashes    {p.flashes_seen} of {p.flashes_shown} seen, flash latency "
            f"{_interval(p.flash_latency)}); camera latency "
            f"{1e3 * p.camera_latency_s:+.2f} ms"
        )
    else:
        lines.append(f"flashes    none of {p.flashes_shown} seen")
    for name, drift in (("offset", p.offset_drift), ("latency", p.latency_drift)):
        if drift is not None:
            lo, hi = drift.ci95_s
            lines.append(
                f"drift      {name}: late - early {1e3 * drift.change_s:+.2f} ms (95% CI "
                f"{1e3 * lo:+.2f} … {1e3 * hi:+.2f} ms)"
            )
    return lines


def _protocol_attrs(p: ProtocolResult) -> dict[str, Any]:
    out: dict[str, Any] = {
        "sync_taps_found": p.taps_found,
        "sync_flashes_shown": p.flashes_shown,
        "sync_flashes_seen": p.flashes_seen,
    }
    for name, e in (("tap_offset", p.offset), ("flash_latency", p.flash_latency)):
        if e is not None:
            out.update(
                {
                    f"sync_{name}_s": e.value_s,
                    f"sync_{name}_ci95_low_s": e.ci95_s[0],
                    f"sync_{name}_ci95_high_s": e.ci95_s[1],
                    f"sync_{name}_events": e.n_used,
                }
            )
    for name, d in (("offset", p.offset_drift), ("latency", p.latency_drift)):
        if d is not None:
            out[f"sync_{name}_drift_s"] = d.change_s
    return out


def _plot(path: Path, report: SyncReport) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    e = report.estimate
    fig, ax = plt.subplots(figsize=(7, 3.5))
    if e.corners:
        ax.errorbar(
            e.corner_times_s,
            e.corner_lags_s * 1e3,
            yerr=1.96e3 * e.corner_std_s,
            fmt="o",
            color="tab:blue",
            capsize=3,
            label=f"lag at each {e.method[:-1]} (95%)",
        )
        ax.axhline(e.offset_s * 1e3, color="tab:red", label=f"offset {e.offset_s * 1e3:+.2f} ms")
        ax.axhspan(e.ci95_s[0] * 1e3, e.ci95_s[1] * 1e3, color="tab:red", alpha=0.2, label="95% CI")
        ax.set_xlabel("time in the session (s)")
        ax.set_ylabel("image time - force time (ms)")
    else:
        model = e.method in (MODEL_METHOD, PULL_HOLD_METHOD)
        ax.plot(
            e.lags_s * 1e3,
            e.correlation,
            color="tab:blue",
            label="model fit" if model else "correlation",
        )
        ax.axvline(e.offset_s * 1e3, color="tab:red", label=f"offset {e.offset_s * 1e3:+.2f} ms")
        ax.axvspan(e.ci95_s[0] * 1e3, e.ci95_s[1] * 1e3, color="tab:red", alpha=0.2, label="95% CI")
        ax.set_xlabel("image time - force time (ms)")
        ax.set_ylabel("fit: minus deviance per frame" if model else "normalized cross-correlation")
    ax.set_title(f"{report.path.name}: {report.verdict}")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=100)
    finally:
        plt.close(fig)


def measure_offset(
    reader: SessionReader, max_lag_s: float = 0.25, settings: ProtocolSettings | None = None
) -> OffsetEstimate:
    """The offset from the viscoelastic model of the whole session when the force has enough
    pulls, holds and releases to pin the tissue's lag (:func:`model_applies`); else, for one pull
    from rest to a hold, from the fit of both whole records (:func:`pull_hold_offset`, the image
    side from a window around the grasp: :func:`grasp_components`); else from
    the force corners when they pin it to within a frame period (95% interval), else the better
    determined of the corner and the change-correlation measurement."""
    t_force, forces = reader.force_times_ns(), reader.forces_n()
    t_frames = reader.frame_times_ns()
    exposure_s = (settings or ProtocolSettings()).exposure_s
    if model_applies(t_force, forces, len(t_frames)):
        components = frame_components(reader)
        return model_offset(t_frames, components, t_force, forces, exposure_s, max_lag_s=max_lag_s)
    found, errors = [], []
    try:  # one pull from rest to a hold: both whole records fitted with the protocol's shape
        return pull_hold_offset(
            t_frames, grasp_components(reader), t_force, forces, exposure_s, max_lag_s=max_lag_s
        )
    except SessionError as err:
        errors.append(str(err))
    components = frame_components(reader)  # only now: a pull-hold session never reads them
    try:
        found.append(corner_offset(t_frames, components, t_force, forces, max_lag_s=max_lag_s))
    except SessionError as err:
        errors.append(str(err))
    period_s = float(np.median(np.diff(t_frames))) / 1e9
    try:
        t_motion, motion = motion_energy(reader)
        found.append(
            change_offset(t_motion, motion, t_force, forces, period_s, max_lag_s=max_lag_s)
        )
    except SessionError as err:
        errors.append(str(err))
    if not found:
        raise SessionError(
            f"{reader.path}: cannot measure the image-force offset: " + "; ".join(errors)
        )
    corners = [e for e in found if e.method == "force corners"]
    if corners and corners[0].ci95_s[1] - corners[0].ci95_s[0] <= 2 * period_s:
        return corners[0]  # sub-frame alignment on the force's kinks: the sharper measurement
    return min(found, key=lambda e: e.ci95_s[1] - e.ci95_s[0])


def _tap_estimate(result: ProtocolResult, path: Path) -> OffsetEstimate:
    """The protocol's tap offset as an :class:`OffsetEstimate` (one lag per tap)."""
    e = result.offset
    if e is None:
        raise SessionError(
            f"{path}: no tap could be measured ({result.taps_found} found in the "
            "force); record the protocol again, tapping briefly and firmly"
        )
    used = e.used
    return OffsetEstimate(
        offset_s=e.value_s,
        std_s=e.std_s,
        ci95_s=e.ci95_s,
        method="taps",
        corner_times_s=e.times_s[used],
        corner_lags_s=e.values_s[used],
        corner_std_s=e.stds_s[used],
    )


def _verdict(
    estimate: OffsetEstimate,
    residual: float,
    protocol: ProtocolResult | None,
    audits: dict[str, StreamAudit],
    limits: SyncLimits,
    recorder_lost: dict[str, int] | None = None,
) -> tuple[str, list[str]]:
    """PASS/FAIL (protocol sessions, or any definite failure) or INCONCLUSIVE (a passive
    estimate too uncertain to judge), with the reasons. A passive estimate passes only when
    its whole 95% interval lies within the limit and fails only when it lies beyond it."""
    half_ci = (estimate.ci95_s[1] - estimate.ci95_s[0]) / 2
    low, high = (c - (estimate.offset_s - residual) for c in estimate.ci95_s)
    failures: list[str] = []
    doubts: list[str] = []
    if abs(residual) > limits.max_offset_s:
        text = f"offset {1e3 * residual:+.2f} ms exceeds ±{1e3 * limits.max_offset_s:g} ms"
        definite = low > limits.max_offset_s or high < -limits.max_offset_s
        (failures if definite or protocol is not None else doubts).append(text)
    elif protocol is None and (low < -limits.max_offset_s or high > limits.max_offset_s):
        doubts.append(
            f"offset {1e3 * residual:+.2f} ms but its 95% CI {1e3 * low:+.2f} … "
            f"{1e3 * high:+.2f} ms reaches beyond ±{1e3 * limits.max_offset_s:g} ms"
        )
    if half_ci > limits.max_ci_halfwidth_s:
        text = (
            f"offset uncertain: 95% CI half-width {1e3 * half_ci:.2f} ms exceeds "
            f"{1e3 * limits.max_ci_halfwidth_s:g} ms"
        )
        (failures if protocol is not None else doubts).append(text)
    for stream, limit in ((CAMERA, limits.max_frame_drop), (FORCE, limits.max_force_drop)):
        if audits[stream].drop_fraction > limit:
            failures.append(
                f"{stream} dropped {100 * audits[stream].drop_fraction:.1f}% "
                f"(limit {100 * limit:g}%){_drop_origin(audits[stream], recorder_lost, stream)}"
            )
    if protocol is not None:
        if protocol.offset is not None and protocol.offset.n_used < MIN_TAPS:
            failures.append(f"only {protocol.offset.n_used} taps measured (need {MIN_TAPS})")
        if protocol.flashes_shown and protocol.flashes_seen < protocol.flashes_shown / 2:
            failures.append(
                f"only {protocol.flashes_seen} of {protocol.flashes_shown} projector "
                "flashes seen (is the projector lighting the view, auto exposure off?)"
            )
        for name, drift in (
            ("image-force offset (taps)", protocol.offset_drift),
            ("camera latency (flashes)", protocol.latency_drift),
        ):
            if drift is None:
                continue
            lo, hi = drift.ci95_s
            if abs(drift.change_s) > limits.max_offset_s and (lo > 0 or hi < 0):
                failures.append(
                    f"{name} changed by {1e3 * drift.change_s:+.2f} ms from the first "
                    "to the second half of the session (a lost frame or a change "
                    "in the camera's buffering?)"
                )
    if failures:
        return FAIL, failures + doubts
    return (INCONCLUSIVE, doubts) if doubts else (PASS, [])


DEVICE_SKIPPED = "never delivered by the device"  # a drop reason's words for device-side drops


def _drop_origin(audit: StreamAudit, recorder_lost: dict[str, int] | None, stream: str) -> str:
    """Where a stream's missing samples were lost, when the session says (newer sessions)."""
    if recorder_lost is None or stream not in recorder_lost:
        return ""
    lost = min(recorder_lost[stream], audit.dropped)
    return f": {audit.dropped - lost} {DEVICE_SKIPPED}, {lost} lost by the recorder"


def _stream_check(reader: SessionReader, name: str, max_lag_s: float) -> OffsetEstimate | str:
    try:
        return stream_offset(reader, name, max_lag_s)
    except SessionError as exc:
        return str(exc)


def verify_sync(
    path: str | Path,
    limits: SyncLimits | None = None,
    plot_path: str | Path | None = None,
    store: bool = True,
    apply_correction: bool = False,
    max_lag_s: float = 0.25,
    settings: ProtocolSettings | None = None,
) -> SyncReport:
    """Measure the image-force offset of a session, audit drops, judge against ``limits``.

    A sync protocol session is measured from its taps and flashes (``settings``: the camera's
    exposure and line time) and judged PASS or FAIL; any other session passively, INCONCLUSIVE
    when its offset is too uncertain to judge. With ``store`` the numbers and verdict go into
    the session's ``/analysis`` attributes; with ``apply_correction`` the measured offset is
    also stored as a frame-time correction, which :class:`SessionReader` applies from then on.
    """
    limits = limits or SyncLimits()
    protocol = None
    with SessionReader(path) as reader:
        if reader.n_frames < 3 or len(reader.forces_n()) < 3:
            raise SessionError(f"{path} has too few frames or force samples to check sync")
        if reader.metadata.get("protocol", {}).get("kind") == "sync":
            protocol = analyse_protocol(reader, settings or ProtocolSettings(), max(max_lag_s, 0.3))
            estimate = _tap_estimate(protocol, Path(path))
        else:
            estimate = measure_offset(reader, max_lag_s, settings)
        previous = int(reader.analysis().get(FRAME_CORRECTION_ATTR, 0)) / 1e9
        fits = {s: reader.clock_fit(s) for s in (CAMERA, FORCE)}
        audits = {s: audit_sequence(reader.stream_times(s)[2]) for s in (CAMERA, FORCE)}
        attrs = reader.attrs
        recorder_lost = {
            s: int(attrs[f"{s}_queue_dropped"])
            for s in (CAMERA, FORCE)
            if f"{s}_queue_dropped" in attrs
        }
        streams = {
            name: _stream_check(reader, name, max_lag_s)
            for name in reader.stream_names()
            if not reader.stream(name).markers
        }
    applied = estimate.offset_s if apply_correction else 0.0
    residual = estimate.offset_s - applied
    verdict, reasons = _verdict(estimate, residual, protocol, audits, limits, recorder_lost)
    report = SyncReport(
        path=Path(path),
        estimate=estimate,
        correction_s=previous + applied,
        residual_offset_s=residual,
        drift_ppm={s: f.drift_ppm for s, f in fits.items()},
        drift_uncertainty_ppm={s: f.drift_uncertainty_ppm for s, f in fits.items()},
        jitter_s={s: f.jitter_ns / 1e9 for s, f in fits.items()},
        audits=audits,
        limits=limits,
        verdict=verdict,
        reasons=reasons,
        plot_path=Path(plot_path) if plot_path else None,
        protocol=protocol,
        streams=streams,
    )
    if report.plot_path is not None:
        _plot(report.plot_path, report)
    if store:
        store_analysis(path, report.to_attrs())
    return report
