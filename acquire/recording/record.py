"""``record_session``: record a session from the rig a configuration describes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vbfe.acquire.image_size import size_mismatch
from vbfe.acquire.recording.acquisition import Acquisition, AcquisitionStats
from vbfe.acquire.recording.listener import Listener
from vbfe.acquire.recording.recorder import Recorder
from vbfe.acquire.recording.settings import RecordConfig
from vbfe.acquire.session.annotate import store_analysis
from vbfe.acquire.session.layout import StreamSpec
from vbfe.acquire.session.reader import FRAME_CORRECTION_ATTR
from vbfe.common.errors import DeviceError, SessionError
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.registry import open_rig
from vbfe.drivers.rig import Rig, RigOptions
from vbfe.drivers.streams.opening import missing_streams

if TYPE_CHECKING:
    from vbfe.acquire.recording.sync_session import SyncProtocol


def record_session(
    config: RecordConfig,
    path: str | Path,
    duration_s: float | None = None,
    operator: str = "",
    notes: str = "",
    conditions: dict[str, Any] | None = None,
    compression: str | None = None,
    calibration_yaml: str | None = None,
    on_progress: Callable[[AcquisitionStats], None] | None = None,
    tare: bool = False,
    overwrite: bool = False,
    protocol: SyncProtocol | None = None,
    calibration_size: tuple[int, int] | None = None,
    calibration_name: str = "the calibration",
    on_warning: Callable[[str], None] | None = None,
    listeners: tuple[Listener, ...] = (),
) -> AcquisitionStats:
    """Record stereo video, force and projector events into ``path`` until ``duration_s``
    seconds of frames are in, a device is gone, or Ctrl-C. With ``tare`` the unloaded trocar
    is zeroed first from ``[record] tare_samples`` samples (not recorded; the offset is
    stored). Simulated rigs add their conditions, description and per-frame ground truth to
    the session. An existing ``path`` is refused unless ``overwrite``. ``calibration_size``
    (the calibration's image size) must match the camera's, checked before recording starts.

    With a sync ``protocol`` the projector flashes and the taps are counted while recording
    (the session's metadata says ``protocol.kind = "sync"``; otherwise ``"traction"``). A
    non-zero ``[record] frame_time_correction_s`` is stored as the session's frame-time
    correction. ``on_warning`` hears of each optional ``[streams]`` entry that was not found;
    further ``listeners`` (e.g. a live viewer) follow the recorder's. Which rig file
    ``config`` came from (or that the simulated bench ran) is stored in the session."""
    settings = config.record
    options = RigOptions()
    if protocol is not None:
        options, duration_s = protocol.rig_options(), protocol.duration_s
    rig = open_rig(config, options)
    check_camera_size(rig, calibration_size, calibration_name)
    listeners = (
        ((protocol,) if protocol else ())
        + ((MissingStreams(on_warning),) if on_warning else ())
        + listeners
    )
    recorder = session_recorder(
        config,
        path,
        rig,
        operator,
        notes,
        conditions,
        compression,
        calibration_yaml,
        overwrite,
        listeners,
    )
    if protocol is not None:
        recorder.metadata["protocol"] = protocol.describe()
    if tare:
        n = settings.tare_samples
        rig.trocar.open()  # the recorder's open keeps it open
        try:
            offset = rig.trocar.tare(n)
        except DeviceError:
            rig.trocar.close()
            raise
        recorder.metadata["tare"] = {"samples": n, "offset_n": offset.tolist()}
    stats = recorder.run(duration_s, on_progress)
    store_frame_correction(config, path)
    return stats


def store_frame_correction(config: RecordConfig, path: str | Path) -> None:
    """Store a non-zero ``[record] frame_time_correction_s`` as the finalized session's
    frame-time correction."""
    correction_s = config.record.frame_time_correction_s
    if correction_s:
        store_analysis(path, {FRAME_CORRECTION_ATTR: int(round(correction_s * 1e9))})


def check_camera_size(
    rig: Rig, calibration_size: tuple[int, int] | None, calibration_name: str = "the calibration"
) -> None:
    """SessionError unless the calibration (when given) is of the camera's image size."""
    if calibration_size is not None:
        mismatch = size_mismatch(
            "the camera gives",
            (rig.camera.width, rig.camera.height),
            calibration_name,
            calibration_size,
        )
        if mismatch:
            raise SessionError(mismatch)


def session_recorder(
    config: RecordConfig,
    path: str | Path,
    rig: Rig,
    operator: str = "",
    notes: str = "",
    conditions: dict[str, Any] | None = None,
    compression: str | None = None,
    calibration_yaml: str | None = None,
    overwrite: bool = False,
    listeners: tuple[Listener, ...] = (),
    streams: tuple[StreamSpec, ...] = (),
    participant: str = "",
    task: str = "",
) -> Recorder:
    """The recorder :func:`record_session` uses (``[record]`` settings, the structured-light
    pattern, a traction session's metadata: operator, participant, task, notes, conditions,
    the rig file ``config`` came from) over ``rig``, with further ``listeners`` and extra
    ``streams``; not started yet."""
    settings = config.record
    metadata: dict[str, Any] = {
        "operator": operator,
        "participant": participant,
        "task": task,
        "notes": notes,
        "conditions": dict(conditions or {}),
        "protocol": {"kind": "traction"},
        "rig": config.banner(),
    }
    return Recorder(
        rig,
        path,
        compression=compression or settings.compression,
        flush_interval_s=settings.flush_interval_s,
        metadata=metadata,
        calibration_yaml=calibration_yaml,
        queue_size=settings.queue_size,
        queue_bytes=int(settings.queue_mb * 1e6),
        min_free_bytes=int(settings.min_free_gb * 1e9),
        pattern=make_pattern,
        overwrite=overwrite,
        listeners=listeners,
        streams=streams,
    )


class MissingStreams(Listener):
    """Reports each optional ``[streams]`` entry that was not found, once the rig is open."""

    def __init__(self, report: Callable[[str], None]) -> None:
        self.report = report

    def on_start(self, acquisition: Acquisition) -> None:
        for warning in missing_streams(acquisition.rig.devices.values()):
            self.report(warning)
