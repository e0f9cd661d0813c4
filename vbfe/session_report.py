"""``vbfe report``: one self-contained HTML page on a session's quality.

Sections: summary; force trace with recorder gaps and sequence drops marked; a strip of frame
thumbnails; per-stream rate and jitter; clock fits and drift; projector events; the sync
verdict stored by verify-sync; the calibration; reconstruction density per frame (clouds
sidecar); live estimates against the trocar. Plots are drawn with matplotlib's Agg canvas and
embedded as PNG, thumbnails as JPEG: the page is one file.
"""

from __future__ import annotations

import datetime
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from vbfe.acquire import SessionReader
from vbfe.acquire.session.audit import audit_sequence
from vbfe.acquire.session.extra_streams import stream_accounting
from vbfe.common.report import HtmlReport, png_bytes

THUMBNAILS = 8
THUMBNAIL_WIDTH = 200
EVENT_ROWS = 40
SECTIONS = (
    "Summary",
    "Force",
    "Frames",
    "Streams",
    "Clocks",
    "Projector events",
    "Sync",
    "Calibration",
    "Reconstruction",
    "Live estimates",
)


def _figure(width: float = 10, height: float = 3.2) -> tuple[Figure, Any]:
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _utc(t_ns: int) -> str:
    moment = datetime.datetime.fromtimestamp(t_ns / 1e9, datetime.timezone.utc)
    return f"{moment:%Y-%m-%d %H:%M:%S} UTC"


def _intervals(t_ns: np.ndarray) -> tuple[float, float, float]:
    """Mean rate (Hz), median interval and jitter (1.4826·MAD of the intervals), ms."""
    if len(t_ns) < 2 or t_ns[-1] <= t_ns[0]:
        return 0.0, float("nan"), float("nan")
    dt = np.diff(t_ns) / 1e6
    median = float(np.median(dt))
    return (
        (len(t_ns) - 1) / ((t_ns[-1] - t_ns[0]) / 1e9),
        median,
        1.4826 * float(np.median(np.abs(dt - median))),
    )


def _summary(page: HtmlReport, r: SessionReader) -> None:
    a, meta = r.attrs, r.metadata
    frame_t = r.frame_times_ns()
    duration = (frame_t[-1] - frame_t[0]) / 1e9 if len(frame_t) > 1 else 0.0
    status = ("complete" if r.complete else "NOT CLOSED CLEANLY") + (
        f" ({a['end_reason']})" if a.get("end_reason") else ""
    )
    conditions = meta.get("conditions") or {}
    page.table(
        ["", ""],
        [
            ("file", str(r.path)),
            ("status", status),
            ("started", _utc(int(a.get("start_utc_ns") or 0))),
            ("operator / notes", f"{meta.get('operator') or '-'} / {meta.get('notes') or '-'}"),
            (
                "participant / task",
                f"{meta.get('participant') or '-'} / {meta.get('task') or '-'}",
            ),
            ("duration", f"{duration:.2f} s"),
            (
                "frames",
                f"{r.n_frames} of {r.frame_size[0]}x{r.frame_size[1]} ({a.get('compression')})",
            ),
            ("force samples", str(len(r.forces_n()))),
            ("protocol", str((meta.get("protocol") or {}).get("kind", "traction"))),
            (
                "conditions",
                ", ".join(
                    f"{k} = {v}"
                    for k, v in sorted(conditions.items())
                    if not isinstance(v, (list, dict))
                )
                or "-",
            ),
        ],
    )


def _force(page: HtmlReport, r: SessionReader, t0: int) -> None:
    forces, t = r.forces_n(), r.force_times_ns()
    page.heading("Force")
    if not len(forces):
        page.paragraph("No force samples.")
        return
    fig, ax = _figure()
    ts = (t - t0) / 1e9
    for k, axis in enumerate(r.force_axes):
        ax.plot(ts, forces[:, k], lw=0.8, label=f"F{axis}")
    ax.plot(ts, np.linalg.norm(forces, axis=1), color="black", lw=1.2, label="|F|")
    _, t_host, seq = r.stream_times("force")
    audit = audit_sequence(seq, max_gaps=1000)
    index = {int(s): i for i, s in enumerate(seq)}
    drops = [ts[index[last]] for last, _ in audit.gaps if last in index]
    for x in drops:
        ax.axvline(x, color="orange", lw=1, alpha=0.8)
    gaps = [g for g in r.gaps() if g["stream"] in ("force", "camera")]
    host0 = plot_zero_host_ns(r, t0)
    for g in gaps:
        ax.axvspan(
            (g["t_host_ns"] - host0) / 1e9,
            (g["t_host_ns"] - host0) / 1e9 + 0.02,
            color="red",
            alpha=0.4,
        )
    marks = marker_times_s(r, host0)
    for x, label in marks:
        ax.axvline(x, color="purple", lw=1.2, ls="--")
        ax.annotate(
            label,
            (x, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(3, -3),
            textcoords="offset points",
            rotation=90,
            va="top",
            fontsize=7,
            color="purple",
        )
    ax.set_xlabel("time since the first frame (s)")
    ax.set_ylabel("force (N)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    page.inline_image(
        png_bytes(fig),
        f"trocar force; purple dashed lines: {len(marks)} markers, orange lines: {len(drops)} "
        f"sequence drops ({audit.dropped} samples), red bands: {len(gaps)} recorder gaps",
    )


def plot_zero_t0_ns(r: SessionReader) -> int:
    """The plots' time zero: the first frame (or force sample) on the session's clock."""
    frame_t, force_t = r.frame_times_ns(), r.force_times_ns()
    return int(frame_t[0]) if len(frame_t) else int(force_t[0]) if len(force_t) else 0


def plot_zero_host_ns(r: SessionReader, t0: int) -> int:
    """The host time of the force plot's zero ``t0``."""
    return int(r.stream_times("force")[1][0] - (r.force_times_ns()[0] - t0))


def marker_times_s(r: SessionReader, host0_ns: int) -> list[tuple[float, str]]:
    """The session's event marks as (seconds after host time ``host0_ns``, text)."""
    return [((e["t_host_ns"] - host0_ns) / 1e9, e["text"]) for e in r.events()]


def _frames(page: HtmlReport, r: SessionReader, t0: int) -> None:
    page.heading("Frames")
    if r.n_frames == 0:
        page.paragraph("No frames.")
        return
    t = r.frame_times_ns()
    strip = []
    for i in np.unique(np.linspace(0, r.n_frames - 1, THUMBNAILS).round().astype(int)):
        image = r.frame(int(i)).left
        h, w = image.shape[:2]
        small = cv2.resize(
            image,
            (THUMBNAIL_WIDTH, max(1, round(h * THUMBNAIL_WIDTH / w))),
            interpolation=cv2.INTER_AREA,
        )
        ok, jpeg = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, 80])
        strip.append((jpeg.tobytes(), f"frame {i}, {(t[i] - t0) / 1e9:.2f} s"))
    page.inline_strip(strip)


def _streams(page: HtmlReport, r: SessionReader) -> None:
    page.heading("Streams")
    rows = []
    for stream in ("camera", "force", "projector"):
        _, t_host, seq = r.stream_times(stream)
        rate, median, jitter = _intervals(t_host)
        audit = audit_sequence(seq)
        gaps = [g for g in r.gaps() if g["stream"] == stream]
        rows.append(
            (
                stream,
                len(t_host),
                f"{rate:.2f}",
                f"{median:.3f}",
                f"{jitter:.3f}",
                audit.dropped,
                f"{100 * audit.drop_fraction:.2f} %",
                len(gaps),
                sum(g["count"] for g in gaps),
            )
        )
    page.table(
        [
            "stream",
            "samples",
            "rate (Hz)",
            "median interval (ms)",
            "interval jitter (ms)",
            "dropped (seq)",
            "drop fraction",
            "recorder gaps",
            "lost in gaps",
        ],
        rows,
    )
    page.paragraph(
        "Rates and intervals from the host arrival times; jitter is 1.4826·MAD of the intervals."
    )
    _extra_streams(page, r)


def _extra_streams(page: HtmlReport, r: SessionReader) -> None:
    """Lost samples (never received) apart from the publisher's irregular time stamps."""
    rows = []
    for name in r.stream_names():
        stream = r.stream(name)
        if stream.markers:
            continue
        acc = stream_accounting(r.attrs, name)
        rows.append(
            (
                name,
                len(stream),
                f"{float(stream.attrs.get('nominal_rate_hz', 0.0)):g}",
                acc.lost,
                acc.irregular_gaps,
                acc.missing_periods,
                f"{acc.worst_gap_ns / 1e6:.1f}",
            )
        )
    if not rows:
        return
    page.table(
        [
            "extra stream",
            "samples",
            "nominal rate (Hz)",
            "lost (never received)",
            "late/irregular publisher gaps",
            "periods without a sample",
            "worst gap (ms)",
        ],
        rows,
    )
    page.paragraph(
        "Lost: samples the recorder never received (the inlet's buffer overflowed, a full "
        "queue). Late/irregular publisher: steps of the publisher's own time stamps over 1.5 "
        "sample periods; it sent nothing then, and nothing was lost."
    )


def _clocks(page: HtmlReport, r: SessionReader) -> None:
    page.heading("Clocks")
    rows, fig, ax = [], *_figure(10, 2.8)
    for stream in ("camera", "force"):
        fit = r.clock_fit(stream)
        t_dev, t_host, _ = r.stream_times(stream)
        rows.append(
            (
                stream,
                f"{fit.drift_ppm:+.1f} ± {fit.drift_uncertainty_ppm:.1f}",
                f"{fit.offset_ns / 1e9:.6f}",
                f"{fit.latency_ns / 1e6:.3f}",
                f"{fit.jitter_ns / 1e6:.3f}",
                fit.n_pairs,
            )
        )
        if len(t_dev) > 1:
            residual = (t_host - fit.to_host(t_dev)) / 1e6
            ax.plot((t_host - t_host[0]) / 1e9, residual, ".", ms=2, label=stream)
    page.table(
        [
            "stream",
            "drift (ppm)",
            "host − device offset (s)",
            "latency (ms)",
            "jitter (ms)",
            "pairs",
        ],
        rows,
    )
    ax.set_xlabel("time (s)")
    ax.set_ylabel("arrival − fit (ms)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    page.inline_image(
        png_bytes(fig),
        "host arrival minus the device→host clock fit: a "
        "trend left in it is drift the fit missed, the spread is transport jitter",
    )
    pairs = r.clock_pairs()
    if len(pairs) > 1:
        offset = (pairs[:, 0] - pairs[:, 1]) / 1e6
        page.paragraph(
            f"{len(pairs)} wall-clock pairs: UTC − host offset varies by "
            f"{offset.max() - offset.min():.3f} ms over the session."
        )


def _projector(page: HtmlReport, r: SessionReader, t0: int) -> None:
    events = r.projector_events()
    page.heading("Projector events")
    if not events:
        page.paragraph("No projector events.")
        return
    host0 = r.stream_times("camera")[1][0] if r.n_frames else events[0].t_host_ns
    page.table(
        ["time (s, host)", "pattern", "frame ID", "seq"],
        [
            (f"{(e.t_host_ns - host0) / 1e9:.3f}", e.pattern, e.frame_id, e.seq)
            for e in events[:EVENT_ROWS]
        ],
    )
    if len(events) > EVENT_ROWS:
        page.paragraph(f"… and {len(events) - EVENT_ROWS} more.")


def _sync(page: HtmlReport, r: SessionReader) -> None:
    page.heading("Sync")
    a = r.analysis()
    if "sync_verdict" not in a:
        page.paragraph("Not verified: run `vbfe verify-sync` on the session.")
        return
    reasons = json.loads(a.get("sync_reasons", "[]") or "[]")
    rows = [
        ("verdict", str(a["sync_verdict"]).upper()),
        ("protocol", a.get("sync_protocol", "")),
        ("image − force offset", f"{1e3 * a['sync_offset_s']:+.2f} ms"),
        (
            "95 % interval",
            f"{1e3 * a.get('sync_offset_ci95_low_s', np.nan):+.2f} … "
            f"{1e3 * a.get('sync_offset_ci95_high_s', np.nan):+.2f} ms",
        ),
        ("residual after correction", f"{1e3 * a.get('sync_residual_offset_s', np.nan):+.2f} ms"),
        ("frame-time correction", f"{a.get('frame_time_correction_ns', 0) / 1e6:+.2f} ms"),
    ]
    rows += [("reason", reason) for reason in reasons]
    page.table(["", ""], rows)


def _calibration(page: HtmlReport, r: SessionReader) -> None:
    page.heading("Calibration")
    text = r.calibration_yaml()
    if text is None:
        page.paragraph(
            "No calibration stored: `vbfe calibrate stereo` and `--calib`, or "
            "`reconstruct --calib`."
        )
        return
    from vbfe.calib import Calibration
    from vbfe.calib.report import summary_rows
    from vbfe.common.errors import CalibrationError

    try:
        page.table(["quantity", "value"], summary_rows(Calibration.from_yaml_text(text)))
    except CalibrationError as exc:
        page.paragraph(f"The stored calibration cannot be read: {exc}")


def _reconstruction(page: HtmlReport, clouds_path: Path | None, t0: int) -> None:
    page.heading("Reconstruction")
    if clouds_path is None or not clouds_path.is_file():
        page.paragraph("No clouds file: `vbfe reconstruct SESSION.h5` writes SESSION.clouds.h5.")
        return
    from vbfe.common.errors import ReconError
    from vbfe.recon import CloudReader

    try:
        with CloudReader(clouds_path) as clouds:
            density = clouds.frame_table("valid_fraction").astype(float)
            decoded = clouds.frame_table("decoded_fraction").astype(float)
            t = clouds.frame_table("t_host_ns")
    except ReconError as exc:
        page.paragraph(str(exc))
        return
    fig, ax = _figure(10, 2.8)
    ts = (t - t0) / 1e9
    ax.plot(ts, 100 * density, label="density (pixels with a point)")
    if np.isfinite(decoded).any():
        ax.plot(ts, 100 * decoded, label="De Bruijn code readable")
    ax.set_xlabel("time since the first frame (s)")
    ax.set_ylabel("%")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    page.inline_image(
        png_bytes(fig),
        f"{clouds_path.name}: {len(density)} frames, median "
        f"density {100 * np.nanmedian(density):.1f} %, lowest "
        f"{100 * np.nanmin(density):.1f} %",
    )


def _estimates(page: HtmlReport, r: SessionReader, t0: int) -> None:
    page.heading("Live estimates")
    e = r.estimates()
    if e is None or not len(e):
        page.paragraph("No live estimates (sessions recorded by `vbfe live --record` have them).")
        return
    from vbfe.estimate.dataset import force_target

    _, _, seq = r.stream_times("camera")
    rows = {int(s): i for i, s in enumerate(seq)}
    at = np.array([rows.get(int(s), -1) for s in e.frame_seq])
    known = at >= 0
    target = str(e.attrs.get("target", "magnitude"))
    measured = np.full(len(e), np.nan)
    if known.any():
        values = force_target(r.force_at_frames()[at[known]], target)
        measured[known] = np.linalg.norm(values, axis=1) if values.shape[1] > 1 else values[:, 0]
    estimated = np.linalg.norm(e.force_n, axis=1) if e.force_n.shape[1] > 1 else e.force_n[:, 0]
    t = (r.frame_times_ns()[np.clip(at, 0, None)] - t0) / 1e9
    fig, ax = _figure(10, 2.8)
    ax.plot(t[known], measured[known], color="black", label="trocar")
    if e.lo_n is not None and e.hi_n is not None and e.force_n.shape[1] == 1:
        order = np.argsort(t[known])
        ax.fill_between(
            t[known][order],
            e.lo_n[known, 0][order],
            e.hi_n[known, 0][order],
            alpha=0.25,
            lw=0,
            label="prediction interval",
        )
    ax.plot(t[known], estimated[known], ".", ms=3, label="live estimate")
    if e.ood is not None and (e.ood & known).any():
        flagged = e.ood & known
        ax.plot(
            t[flagged],
            estimated[flagged],
            "x",
            color="red",
            ms=5,
            label="outside the training data",
        )
    ax.set_xlabel("time since the first frame (s)")
    ax.set_ylabel(f"{'|F|' if target in ('magnitude', 'xyz') else 'F' + target} (N)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    both = known & np.isfinite(measured) & np.isfinite(estimated)
    mae = float(np.mean(np.abs(estimated[both] - measured[both]))) if both.any() else float("nan")
    latency = e.latency_s * 1e3
    page.inline_image(
        png_bytes(fig),
        f"{len(e)} estimates ({e.attrs.get('target', '')}); MAE "
        f"{mae:.3f} N against the trocar on {int(both.sum())} frames; latency "
        f"p50 {np.percentile(latency, 50):.1f} ms, p95 "
        f"{np.percentile(latency, 95):.1f} ms"
        + (
            f"; {int(e.ood.sum())} estimates from frames outside the training data"
            if e.ood is not None
            else ""
        ),
    )


def session_page(session_path: str | Path, clouds_path: str | Path | None = None) -> HtmlReport:
    """The report page of one session (clouds default: the sidecar beside it)."""
    from vbfe.recon import sidecar_path

    clouds = Path(clouds_path) if clouds_path is not None else sidecar_path(session_path)
    with SessionReader(session_path) as r:
        page = HtmlReport(f"Session {Path(session_path).name}")
        t0 = plot_zero_t0_ns(r)
        page.heading("Summary")
        _summary(page, r)
        _force(page, r, t0)
        _frames(page, r, t0)
        _streams(page, r)
        _clocks(page, r)
        _projector(page, r, t0)
        _sync(page, r)
        _calibration(page, r)
        _reconstruction(page, clouds, t0)
        _estimates(page, r, t0)
    return page


def write_session_report(
    session_path: str | Path, out_path: str | Path, clouds_path: str | Path | None = None
) -> Path:
    """Write the page of one session to ``out_path``; returns its path."""
    return session_page(session_path, clouds_path).write(out_path)
