"""``record_session``: record a session from the rig a configuration describes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vbfe.acquire.reader import FRAME_CORRECTION_ATTR, store_analysis
from vbfe.acquire.recorder import Recorder, RecorderStats
from vbfe.config import section
from vbfe.drivers.registry import open_devices

if TYPE_CHECKING:
    from vbfe.acquire.sync_session import SyncProtocol


def record_session(config: dict[str, dict[str, Any]], path: str | Path,
                   duration_s: float | None = None, operator: str = "", notes: str = "",
                   conditions: dict[str, Any] | None = None, compression: str | None = None,
                   calibration_yaml: str | None = None,
                   on_progress: Callable[[RecorderStats], None] | None = None,
                   protocol: SyncProtocol | None = None) -> RecorderStats:
    """Record stereo video, force and projector events into ``path`` until ``duration_s``
    seconds of frames are in, a device is gone, or Ctrl-C. Simulated benches add their
    conditions, description and per-frame ground truth to the session.

    With a sync ``protocol`` the projector flashes and the taps are counted while recording
    (the session's metadata says ``protocol.kind = "sync"``; otherwise ``"traction"``). A
    non-zero ``[record] frame_time_correction_s`` is stored as the session's frame-time
    correction."""
    from vbfe.recon.pattern import make_pattern

    settings = section(config, "record")
    if protocol is not None:
        config = protocol.bench_config(config)
        duration_s = protocol.duration_s
    devices = open_devices(config)
    metadata: dict[str, Any] = {"operator": operator, "notes": notes,
                                "conditions": dict(conditions or {}),
                                "protocol": protocol.describe() if protocol else {"kind": "traction"}}
    if devices.bench is not None:
        metadata["conditions"] = {**devices.bench.conditions(), **metadata["conditions"]}
        metadata["bench"] = devices.bench.describe()
    projector = devices.projector
    recorder = Recorder(devices, path, compression=compression or settings["compression"],
                        flush_interval_s=float(settings["flush_interval_s"]),
                        metadata=metadata, calibration_yaml=calibration_yaml,
                        queue_size=int(settings["queue_size"]),
                        min_free_bytes=int(float(settings["min_free_gb"]) * 1e9),
                        pattern=make_pattern(projector.width, projector.height),
                        pattern_name="debruijn-hsv",
                        on_forces=protocol.tap_counter.feed if protocol else None)
    recorder.start()
    stats = recorder.run(duration_s, on_progress, on_tick=protocol.tick if protocol else None)
    correction_s = float(settings.get("frame_time_correction_s", 0.0))
    if correction_s:
        store_analysis(path, {FRAME_CORRECTION_ATTR: int(round(correction_s * 1e9))})
    return stats
