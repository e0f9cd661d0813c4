"""``record_session``: record a session from the rig a configuration describes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from vbfe.acquire.recorder import Recorder, RecorderStats
from vbfe.config import section
from vbfe.drivers.errors import DeviceError
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.registry import Devices, open_devices


def record_session(config: dict[str, dict[str, Any]], path: str | Path,
                   duration_s: float | None = None, operator: str = "", notes: str = "",
                   conditions: dict[str, Any] | None = None, compression: str | None = None,
                   calibration_yaml: str | None = None,
                   on_progress: Callable[[RecorderStats], None] | None = None,
                   tare: bool = False, overwrite: bool = False) -> RecorderStats:
    """Record stereo video, force and projector events into ``path`` until ``duration_s``
    seconds of frames are in, a device is gone, or Ctrl-C. With ``tare`` the unloaded trocar
    is zeroed first from ``[record] tare_samples`` samples (not recorded; the offset is
    stored). Simulated benches add their conditions, description and per-frame ground truth to
    the session. An existing ``path`` is refused unless ``overwrite``."""
    devices = open_devices(config)
    recorder = session_recorder(config, path, devices, operator, notes, conditions,
                                compression, calibration_yaml, overwrite)
    if tare:
        n = int(section(config, "record").get("tare_samples", 500))
        devices.trocar.open()  # the recorder's open keeps it open
        try:
            offset = devices.trocar.tare(n)
        except DeviceError:
            devices.trocar.close()
            raise
        recorder.metadata["tare"] = {"samples": n, "offset_n": offset.tolist()}
    recorder.start()
    return recorder.run(duration_s, on_progress)


def session_recorder(config: dict[str, dict[str, Any]], path: str | Path, devices: Devices,
                     operator: str = "", notes: str = "",
                     conditions: dict[str, Any] | None = None, compression: str | None = None,
                     calibration_yaml: str | None = None, overwrite: bool = False) -> Recorder:
    """The recorder :func:`record_session` uses, over given devices (which may be wrapped,
    e.g. by a live estimator that sees every frame); not started yet."""
    settings = section(config, "record")
    metadata: dict[str, Any] = {"operator": operator, "notes": notes,
                                "conditions": dict(conditions or {})}
    if devices.bench is not None:
        metadata["conditions"] = {**devices.bench.conditions(), **metadata["conditions"]}
        metadata["bench"] = devices.bench.describe()
    return Recorder(devices, path, compression=compression or settings["compression"],
                    flush_interval_s=float(settings["flush_interval_s"]),
                    metadata=metadata, calibration_yaml=calibration_yaml,
                    queue_size=int(settings["queue_size"]),
                    min_free_bytes=int(float(settings["min_free_gb"]) * 1e9),
                    pattern=make_pattern, pattern_name="debruijn-hsv", overwrite=overwrite)
