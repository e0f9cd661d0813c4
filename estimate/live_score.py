"""Scoring a session's live estimate stream against its trocar, on synchronised times."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vbfe.acquire import SessionReader
from vbfe.common.errors import EstimateError
from vbfe.estimate.evaluation import error_stats
from vbfe.estimate.preparation import force_target, target_label
from vbfe.estimate.report import plot_session, write_json


def score_live_stream(
    session_path: str | Path, out_dir: str | Path | None = None
) -> dict[str, Any]:
    """Error of the stored live estimates against the trocar force at each source frame's
    synchronised time, with the latency, rate and skipped frames; with ``out_dir`` also
    ``live_metrics.json`` and a plot of estimate and trocar over time."""
    with SessionReader(session_path) as reader:
        stream = reader.estimates()
        if stream is None or not len(stream):
            raise EstimateError(
                f"{session_path} holds no live estimates; record them with "
                f"'vbfe live --model MODEL.pt --record {Path(session_path).name}'"
            )
        seqs = reader.stream_times("camera")[2][: reader.n_frames]
        times = reader.frame_times_ns()
        forces = reader.force_at_frames()
    index = {int(s): i for i, s in enumerate(seqs)}
    rows = np.array([index.get(int(s), -1) for s in stream.frame_seq])
    target = str(stream.attrs.get("target", "magnitude"))
    measured = force_target(forces[rows.clip(0)], target)
    usable = (
        (rows >= 0) & np.isfinite(stream.force_n).all(axis=1) & np.isfinite(measured).all(axis=1)
    )
    if not usable.any():
        raise EstimateError(
            f"no live estimate of {session_path} has a recorded frame with a "
            "trocar force to compare with"
        )
    latency_ms = stream.latency_s * 1e3
    span_s = (stream.t_ready_host_ns[-1] - stream.t_ready_host_ns[0]) / 1e9
    result: dict[str, Any] = {
        "session": str(session_path),
        "target": target,
        "units": "N",
        "error": error_stats(stream.force_n[usable], measured[usable]),
        "estimates": len(stream),
        "compared": int(usable.sum()),
        "not_recorded_frames": int((rows < 0).sum()),
        "no_cloud": int((~np.isfinite(stream.force_n).all(axis=1)).sum()),
        "skipped_frames": int(stream.attrs.get("skipped_frames", 0)),
        "rate_hz": (len(stream) - 1) / span_s if span_s > 0 else 0.0,
        "latency_ms": {
            "p50": float(np.percentile(latency_ms, 50)),
            "p95": float(np.percentile(latency_ms, 95)),
        },
        "stage_median_ms": {
            name: float(np.median(stream.stage_s[:, k]) * 1e3)
            for k, name in enumerate(stream.stages)
        },
    }
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        result["files"] = [
            str(write_json(out / "live_metrics.json", result)),
            str(
                plot_session(
                    out / "live_force.png",
                    f"{Path(session_path).name}: live estimate vs trocar",
                    times[rows[usable]],
                    measured[usable],
                    {"live": stream.force_n[usable]},
                    target_label(target),
                    "live",
                )
            ),
        ]
    return result
