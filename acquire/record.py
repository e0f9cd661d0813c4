"""``record_session``: record a session from the rig a configuration describes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from vbfe.acquire.errors import SessionError
from vbfe.acquire.record_settings import record_settings
from vbfe.acquire.recorder import Recorder, RecorderStats
from vbfe.drivers.registry import open_devices


def record_session(config: dict[str, dict[str, Any]], path: str | Path,
                   duration_s: float | None = None, operator: str = "", notes: str = "",
                   conditions: dict[str, Any] | None = None, compression: str | None = None,
                   calibration_yaml: str | None = None,
                   calibration_size: tuple[int, int] | None = None,
                   calibration_name: str = "the calibration",
                   on_progress: Callable[[RecorderStats], None] | None = None) -> RecorderStats:
    """Record stereo video, force and projector events into ``path`` until ``duration_s``
    seconds of frames are in, a device is gone, or Ctrl-C. Simulated benches add their
    conditions, description and per-frame ground truth to the session. ``calibration_size``
    (the calibration's image size) must match the camera's, checked before recording starts."""
    from vbfe.recon.pattern import make_pattern

    settings = record_settings(config)
    devices = open_devices(config)
    camera_size = (devices.camera.width, devices.camera.height)
    if calibration_size is not None and tuple(calibration_size) != camera_size:
        raise SessionError(f"{calibration_name} is for {calibration_size[0]}x"
                           f"{calibration_size[1]} images but the camera gives {camera_size[0]}x{camera_size[1]}; "
                           "calibrate at this resolution or change the camera's size")
    metadata: dict[str, Any] = {"operator": operator, "notes": notes,
                                "conditions": dict(conditions or {})}
    if devices.bench is not None:
        metadata["conditions"] = {**devices.bench.conditions(), **metadata["conditions"]}
        metadata["bench"] = devices.bench.describe()
    projector = devices.projector
    recorder = Recorder(devices, path, compression=compression or settings.compression,
                        flush_interval_s=settings.flush_interval_s,
                        metadata=metadata, calibration_yaml=calibration_yaml,
                        queue_size=settings.queue_size,
                        min_free_bytes=int(settings.min_free_gb * 1e9),
                        pattern=make_pattern(projector.width, projector.height),
                        pattern_name="debruijn-hsv")
    recorder.start()
    return recorder.run(duration_s, on_progress)
