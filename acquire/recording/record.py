"""``record_session``: record a session from the rig a configuration describes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vbfe.acquire.errors import SessionError
from vbfe.acquire.session.reader import FRAME_CORRECTION_ATTR, store_analysis
from vbfe.acquire.recording.settings import record_settings
from vbfe.acquire.recording.recorder import Recorder, RecorderStats
from vbfe.drivers.errors import DeviceError
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.registry import Devices, open_devices

if TYPE_CHECKING:
    from vbfe.acquire.recording.sync_session import SyncProtocol


def record_session(config: dict[str, dict[str, Any]], path: str | Path,
                   duration_s: float | None = None, operator: str = "", notes: str = "",
                   conditions: dict[str, Any] | None = None, compression: str | None = None,
                   calibration_yaml: str | None = None,
                   on_progress: Callable[[RecorderStats], None] | None = None,
                   tare: bool = False, overwrite: bool = False,
                   protocol: SyncProtocol | None = None,
                   calibration_size: tuple[int, int] | None = None,
                   calibration_name: str = "the calibration") -> RecorderStats:
    """Record stereo video, force and projector events into ``path`` until ``duration_s``
    seconds of frames are in, a device is gone, or Ctrl-C. With ``tare`` the unloaded trocar
    is zeroed first from ``[record] tare_samples`` samples (not recorded; the offset is
    stored). Simulated benches add their conditions, description and per-frame ground truth to
    the session. An existing ``path`` is refused unless ``overwrite``. ``calibration_size``
    (the calibration's image size) must match the camera's, checked before recording starts.

    With a sync ``protocol`` the projector flashes and the taps are counted while recording
    (the session's metadata says ``protocol.kind = "sync"``; otherwise ``"traction"``). A
    non-zero ``[record] frame_time_correction_s`` is stored as the session's frame-time
    correction."""
    settings = record_settings(config)
    if protocol is not None:
        config = protocol.bench_config(config)
        duration_s = protocol.duration_s
    devices = open_devices(config)
    camera_size = (devices.camera.width, devices.camera.height)
    if calibration_size is not None and tuple(calibration_size) != camera_size:
        raise SessionError(f"{calibration_name} is for {calibration_size[0]}x"
                           f"{calibration_size[1]} images but the camera gives {camera_size[0]}x"
                           f"{camera_size[1]}; calibrate at this resolution or change the "
                           "camera's size")
    recorder = session_recorder(config, path, devices, operator, notes, conditions,
                                compression, calibration_yaml, overwrite, protocol)
    if tare:
        n = settings.tare_samples
        devices.trocar.open()  # the recorder's open keeps it open
        try:
            offset = devices.trocar.tare(n)
        except DeviceError:
            devices.trocar.close()
            raise
        recorder.metadata["tare"] = {"samples": n, "offset_n": offset.tolist()}
    recorder.start()
    stats = recorder.run(duration_s, on_progress, on_tick=protocol.tick if protocol else None)
    if settings.frame_time_correction_s:
        store_analysis(path, {FRAME_CORRECTION_ATTR:
                              int(round(settings.frame_time_correction_s * 1e9))})
    return stats


def session_recorder(config: dict[str, dict[str, Any]], path: str | Path, devices: Devices,
                     operator: str = "", notes: str = "",
                     conditions: dict[str, Any] | None = None, compression: str | None = None,
                     calibration_yaml: str | None = None, overwrite: bool = False,
                     protocol: SyncProtocol | None = None) -> Recorder:
    """The recorder :func:`record_session` uses, over given devices (which may be wrapped,
    e.g. by a live estimator that sees every frame); not started yet."""
    settings = record_settings(config)
    metadata: dict[str, Any] = {"operator": operator, "notes": notes,
                                "conditions": dict(conditions or {}),
                                "protocol": protocol.describe() if protocol else {"kind": "traction"}}
    if devices.bench is not None:
        metadata["conditions"] = {**devices.bench.conditions(), **metadata["conditions"]}
        metadata["bench"] = devices.bench.describe()
    return Recorder(devices, path, compression=compression or settings.compression,
                    flush_interval_s=settings.flush_interval_s,
                    metadata=metadata, calibration_yaml=calibration_yaml,
                    queue_size=settings.queue_size,
                    min_free_bytes=int(settings.min_free_gb * 1e9),
                    pattern=make_pattern, pattern_name="debruijn-hsv", overwrite=overwrite,
                    on_forces=protocol.tap_counter.feed if protocol else None)
