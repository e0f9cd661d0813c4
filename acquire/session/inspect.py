"""``inspect_session``: a summary of a session file for the operator."""

from __future__ import annotations

import datetime
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vbfe.acquire.session.audit import StreamAudit, audit_sequence
from vbfe.acquire.session.clock import ClockFit
from vbfe.acquire.session.estimates import EstimateStream
from vbfe.acquire.session.extra_streams import RecordedStream, stream_accounting
from vbfe.acquire.session.layout import CAMERA, FORCE, PROJECTOR
from vbfe.acquire.session.reader import SessionReader


@dataclass
class SessionSummary:
    """Counts, timing, drops, gaps and clock fits of one session."""

    path: Path
    truncated: bool  # the recorder did not close the file (crash, power loss, SIGKILL)
    growing: bool  # ... because it is still recording
    attrs: dict[str, Any]
    metadata: dict[str, Any]
    duration_s: float
    frame_size: tuple[int, int]
    audits: dict[str, StreamAudit]
    rates_hz: dict[str, float]
    clocks: dict[str, ClockFit]
    gaps: list[dict[str, Any]]
    patterns: list[str]
    has_calibration: bool
    truth_names: list[str]
    analysis: dict[str, Any] = field(default_factory=dict)
    estimates: EstimateStream | None = None
    streams: list[RecordedStream] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)

    def _stream_line(self, s: RecordedStream) -> str:
        span_s = (s.t_host_ns[-1] - s.t_host_ns[0]) / 1e9 if len(s) > 1 else 0.0
        rate = (len(s) - 1) / span_s if span_s > 0 else 0.0
        nominal = float(s.attrs.get("nominal_rate_hz", 0.0))
        channels = ", ".join(
            f"{c} [{u}]" if u else c for c, u in zip(s.channels, s.units, strict=False)
        )
        correction = (
            f"; time correction {s.corrections[-1, 1] / 1e6:+.3f} ms" if len(s.corrections) else ""
        )
        what = (
            "markers"
            if s.markers
            else f"samples at {rate:.1f} Hz (nominal {nominal:g}), "
            + stream_accounting(self.attrs, s.name).text(len(s))
        )
        return (
            f"stream    {s.name}: {len(s)} {what}; LSL {s.attrs.get('lsl_name')!r} "
            f"from {s.attrs.get('hostname') or '?'}{correction}; channels {channels}"
        )

    def text(self) -> str:
        """The summary as lines of text."""
        a = self.attrs
        start = datetime.datetime.fromtimestamp(
            int(a.get("start_utc_ns", 0)) / 1e9, datetime.timezone.utc
        )
        status = (
            f"complete ({a.get('end_reason', 'closed')})"
            if not self.truncated
            else "BEING RECORDED: the recorder is still writing; this is what it flushed so far"
            if self.growing
            else "NOT CLOSED CLEANLY: the recorder stopped mid-recording; everything up to its "
            "last flush is readable"
        )
        lines = [
            f"session   {self.path}",
            f"format    schema {a.get('schema_version')}, written by vbfe "
            f"{a.get('software_version')}, compression {a.get('compression')}",
            f"status    {status}",
            f"started   {start:%Y-%m-%d %H:%M:%S} UTC, operator {a.get('operator') or '-'}"
            f", notes {a.get('notes') or '-'}",
            f"rig       {self.metadata.get('rig') or '-'}",
            f"duration  {self.duration_s:.3f} s",
        ]
        w, h = self.frame_size
        for stream, unit in ((CAMERA, "frames"), (FORCE, "samples")):
            au = self.audits[stream]
            extra = f" {w}x{h}" if stream == CAMERA else ""
            queue = a.get(f"{stream}_queue_dropped")
            at_end = sum(
                g["count"] for g in self.gaps if g["stream"] == stream and g["next_seq"] < 0
            )  # lost after the last stored sample
            dropped = au.dropped + at_end
            lines.append(
                f"{stream:<9} {au.stored} {unit}{extra} at {self.rates_hz[stream]:.2f} Hz;"
                f" dropped {dropped} ({100 * dropped / max(au.expected + at_end, 1):.2f}%)"
                + (f", of which {queue} by a full queue" if queue else "")
                + f", duplicated {au.duplicated}, out of order {au.reordered}"
            )
        lines.append(f"projector {len(self.patterns)} events: {', '.join(self.patterns) or '-'}")
        for stream, fit in self.clocks.items():
            if stream != PROJECTOR:
                lines.append(
                    f"clock     {stream}: host - device offset {fit.offset_ns / 1e9:.6f} s,"
                    f" drift {fit.drift_ppm:+.1f} ± {fit.drift_uncertainty_ppm:.1f} ppm,"
                    f" jitter {fit.jitter_ns / 1e6:.3f} ms"
                    f" ({fit.n_pairs} pairs)"
                )
        for gap in self.gaps:
            after = "end" if gap["next_seq"] < 0 else f"seq {gap['next_seq']}"
            lines.append(
                f"gap       {gap['stream']}: {gap['reason']} after seq {gap['last_seq']}"
                f" until {after} ({gap['count']} lost)"
            )
        for stream in (CAMERA, FORCE):
            for last, nxt in self.audits[stream].gaps[:10]:
                lines.append(f"gap       {stream}: sequence jumps {last} -> {nxt}")
        lines += [self._stream_line(s) for s in self.streams]
        start_ns = int(a.get("start_host_ns", 0))
        for event in self.events[:20]:
            lines.append(
                f"event     {(event['t_host_ns'] - start_ns) / 1e9:8.3f} s "
                f"{event['source']}: {event['text']}"
            )
        if len(self.events) > 20:
            lines.append(f"event     … {len(self.events) - 20} more")
        lines.append(f"calib     {'stored' if self.has_calibration else 'none'}")
        if self.truth_names:
            lines.append(f"truth     {', '.join(self.truth_names)}")
        if self.metadata.get("conditions"):
            lines.append(f"conditions {self.metadata['conditions']}")
        if self.estimates is not None:
            e = self.estimates
            latency = e.latency_s * 1e3 if len(e) else [float("nan")]
            lines.append(
                f"estimate  {len(e)} live estimates ({e.attrs.get('target')}), "
                f"{e.attrs.get('skipped_frames', 0)} frames skipped; latency p50 "
                f"{np.percentile(latency, 50):.1f} ms, p95 {np.percentile(latency, 95):.1f}"
                f" ms (score: vbfe evaluate --live)"
            )
        if "sync_verdict" in self.analysis:
            lines.append(
                f"sync      {self.analysis['sync_verdict']}: image - force offset "
                f"{1e3 * self.analysis['sync_offset_s']:+.2f} ms"
            )
        return "\n".join(lines)


def inspect_session(path: str | Path) -> SessionSummary:
    """Summarize a session; raises SessionError when it is not a readable session."""
    with SessionReader(path) as s:
        audits = {stream: audit_sequence(s.stream_times(stream)[2]) for stream in (CAMERA, FORCE)}
        frame_t = s.frame_times_ns()
        force_t = s.force_times_ns()
        spans = [t[-1] - t[0] for t in (frame_t, force_t) if len(t) > 1]
        rates = {
            name: (len(t) - 1) / ((t[-1] - t[0]) / 1e9) if len(t) > 1 and t[-1] > t[0] else 0.0
            for name, t in ((CAMERA, frame_t), (FORCE, force_t))
        }
        return SessionSummary(
            path=Path(path),
            truncated=not s.closed_cleanly or not s.complete,
            growing=s.growing,
            attrs=s.attrs,
            metadata=s.metadata,
            duration_s=float(max(spans, default=0)) / 1e9,
            frame_size=s.frame_size,
            audits=audits,
            rates_hz=rates,
            clocks={stream: s.clock_fit(stream) for stream in (CAMERA, FORCE, PROJECTOR)},
            gaps=s.gaps(),
            patterns=[e.pattern for e in s.projector_events()],
            has_calibration=s.calibration_yaml() is not None,
            truth_names=s.truth_names(),
            analysis=s.analysis(),
            estimates=s.estimates(),
            streams=[s.stream(name) for name in s.stream_names()],
            events=s.events(),
        )
