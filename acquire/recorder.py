"""The recorder: per-device reader threads → bounded queues → one writer thread → HDF5.

A full queue never blocks a device: the sample is dropped, counted and marked as a gap. The
writer flushes at least every ``flush_interval_s`` (SWMR), so a crash loses at most that much.
A device that vanishes ends the session cleanly with what was recorded and a marked gap.
A recording of a given duration keeps exactly the frames and force samples that arrived (host
clock) before its end: when the duration is reached, the force reader goes on until it has read
past the end, so which samples are kept never depends on when the threads happened to stop.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vbfe.acquire.errors import SessionError
from vbfe.acquire.storage import check_destination, free_bytes
from vbfe.acquire.writer import SessionWriter, finalize_session
from vbfe.drivers.errors import DeviceError
from vbfe.drivers.registry import Devices
from vbfe.drivers.samples import StereoFrame

_READ_TIMEOUT_S = 0.2
_FRAME_BATCH = 4
_END_GRACE_S = 2.0  # how long a reader may go on after the stop to reach the recording's end


@dataclass
class RecorderStats:
    """Progress of a recording, as shown on the progress line."""

    elapsed_s: float = 0.0  # span of recorded frame host times
    wall_s: float = 0.0
    frames: int = 0
    samples: int = 0
    events: int = 0
    flushed: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)  # queue overflows + device-side drops
    bytes_written: int = 0
    end_reason: str = ""

    @property
    def write_rate_mb_s(self) -> float:
        """Uncompressed payload written per wall-clock second, in MB/s."""
        return self.bytes_written / 1e6 / self.wall_s if self.wall_s > 0 else 0.0


class _Pump(threading.Thread):
    """Reads one device into a bounded queue; counts and reports overflow and disconnection."""

    def __init__(self, name: str, read: Callable[[float], Any], out: queue.Queue,
                 control: queue.Queue, stop: threading.Event,
                 read_until_ns: Callable[[], int | None] = lambda: None) -> None:
        super().__init__(name=f"vbfe-read-{name}", daemon=True)
        self.stream, self._read, self._out, self._control, self._halt = name, read, out, control, stop
        self._read_until_ns = read_until_ns
        self.dropped = 0
        self.last_seq = -1
        self.last_host_ns: int | None = None
        self.error: str | None = None
        self._halted_at: float | None = None

    def _done(self) -> bool:
        """Stopped, and past the recording's end (``read_until_ns``) when there is one."""
        if not self._halt.is_set():
            return False
        end_ns = self._read_until_ns()
        if end_ns is None or (self.last_host_ns is not None and self.last_host_ns >= end_ns):
            return True
        if self._halted_at is None:
            self._halted_at = time.monotonic()
        return time.monotonic() - self._halted_at > _END_GRACE_S

    def run(self) -> None:
        burst = 0
        while not self._done():
            try:
                item = self._read(_READ_TIMEOUT_S)
            except DeviceError as exc:
                self.error = str(exc)
                self._control.put(("gap", self.stream, "device disconnected", self.last_seq, -1,
                                   time.monotonic_ns(), 0))
                break
            if item is None:
                continue
            self.last_host_ns = item.t_host_ns
            try:
                self._out.put_nowait(item)
            except queue.Full:
                self.dropped += 1
                burst += 1
                continue
            if burst:
                self._control.put(("gap", self.stream, "queue full", self.last_seq, item.seq,
                                   item.t_host_ns, burst))
                burst = 0
            self.last_seq = item.seq
        if burst:  # samples lost at the very end: no next sequence number
            self._control.put(("gap", self.stream, "queue full", self.last_seq, -1,
                               time.monotonic_ns(), burst))


class Recorder:
    """Record a camera, a force sensor and a projector into one session file.

    Use as ``with Recorder(devices, path) as rec: rec.run(duration_s)`` or call
    :meth:`start` / :meth:`stop` yourself. Devices are opened and closed by the recorder.
    """

    def __init__(self, devices: Devices, path: str | Path, compression: str = "lzf",
                 flush_interval_s: float = 1.0, metadata: dict[str, Any] | None = None,
                 calibration_yaml: str | None = None, queue_size: int = 256,
                 min_free_bytes: int = 1 << 30, pattern: np.ndarray | None = None,
                 pattern_name: str = "debruijn",
                 on_flush: Callable[[RecorderStats], None] | None = None) -> None:
        self.devices = devices
        self.path = check_destination(path, min_free_bytes)
        self.compression = compression
        self.flush_interval_s = flush_interval_s
        self.metadata = dict(metadata or {})
        self.calibration_yaml = calibration_yaml
        self.min_free_bytes = min_free_bytes
        self.pattern, self.pattern_name = pattern, pattern_name
        self.on_flush = on_flush
        self._frames: queue.Queue = queue.Queue(maxsize=queue_size)
        self._forces: queue.Queue = queue.Queue(maxsize=queue_size * 64)
        self._control: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._pumps: list[_Pump] = []
        self._writer_thread: threading.Thread | None = None
        self._writer: SessionWriter | None = None
        self._error: BaseException | None = None
        self._frame_t_device: list[int] = []
        self._frame_t_host = [0, 0]  # first, last
        self._span_limit_ns: int | None = None  # frames later than this after the first are not kept
        self._span_reached = threading.Event()
        self._end_host_ns: int | None = None  # first frame's host time + duration
        self._t_start = 0.0
        self.stats = RecorderStats()

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> None:
        """Open the devices and the file, show the pattern, start reading and writing."""
        cam, trocar, projector = self.devices.camera, self.devices.trocar, self.devices.projector
        try:
            for device in (cam, trocar, projector):
                device.open()
        except DeviceError:
            self._close_devices()
            raise
        self.metadata.setdefault("devices", {"camera": cam.describe(), "trocar": trocar.describe(),
                                             "projector": projector.describe()})
        self._writer = SessionWriter(self.path, (cam.width, cam.height), self.compression,
                                     self.metadata, self.calibration_yaml,
                                     getattr(trocar, "axes", ("x", "y", "z")))
        self._t_start = time.monotonic()
        if self.pattern is not None:
            self._control.put(("event", projector.show(self.pattern, self.pattern_name)))
        self._pumps = [_Pump("camera", cam.read, self._frames, self._control, self._stop),
                       _Pump("force", trocar.read, self._forces, self._control, self._stop,
                             self._reached_end_ns)]
        self._writer_thread = threading.Thread(target=self._write_loop, name="vbfe-writer",
                                               daemon=True)
        self._writer_thread.start()
        for pump in self._pumps:
            pump.start()

    def run(self, duration_s: float | None = None,
            on_progress: Callable[[RecorderStats], None] | None = None,
            progress_interval_s: float = 0.5) -> RecorderStats:
        """Record until ``duration_s`` of frames (host clock) are in, a device is gone, or
        Ctrl-C; then stop cleanly. Returns the final statistics."""
        last_progress = 0.0
        if duration_s is not None:
            self._span_limit_ns = int(duration_s * 1e9)
        try:
            while not self._stop.is_set():
                time.sleep(0.05)
                stats = self._update_stats()
                if on_progress is not None and stats.wall_s - last_progress >= progress_interval_s:
                    on_progress(stats)
                    last_progress = stats.wall_s
                if self._span_reached.is_set():
                    stats.end_reason = "duration reached"
                    break
                dead = [p for p in self._pumps if p.error is not None]
                if dead:
                    stats.end_reason = f"{dead[0].stream} disconnected: {dead[0].error}"
                    break
        except KeyboardInterrupt:
            self.stats.end_reason = "stopped by operator"
        return self.stop()

    def stop(self) -> RecorderStats:
        """Stop reading, write what is queued, close and finalize the file, close the devices."""
        self._stop.set()
        for pump in self._pumps:
            pump.join(timeout=5.0)
        if self._writer_thread is not None:
            self._writer_thread.join()
        self._close_devices()
        stats = self._update_stats()
        if self._error is not None:
            if not isinstance(self._error, (OSError, SessionError)):
                raise self._error  # a bug: keep its traceback
            raise SessionError(f"recording to {self.path} failed: {self._error}; the file holds "
                               "everything up to the last flush") from self._error
        if not stats.end_reason:
            stats.end_reason = "stopped"
        finalize_session(self.path, self._final_attrs(stats), self._truth())
        return stats

    def __enter__(self) -> "Recorder":
        self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: Any) -> None:
        if not self._stop.is_set():
            self.stop()

    # -- internals ------------------------------------------------------------------------
    def _close_devices(self) -> None:
        for device in (self.devices.camera, self.devices.trocar, self.devices.projector):
            with contextlib.suppress(DeviceError):  # a vanished device is already recorded
                device.close()

    def _update_stats(self) -> RecorderStats:
        s = self.stats
        writer = self._writer
        s.wall_s = time.monotonic() - self._t_start
        if writer is not None:
            s.frames, s.samples = writer.counts["camera"], writer.counts["force"]
            s.events = writer.counts["projector"]
            s.flushed = dict(writer.flushed_counts)
            s.bytes_written = writer.bytes_written
        s.elapsed_s = (self._frame_t_host[1] - self._frame_t_host[0]) / 1e9
        device_drops = {"camera": self.devices.camera.stats.dropped,
                        "force": self.devices.trocar.stats.dropped}
        s.dropped = {p.stream: p.dropped + device_drops[p.stream] for p in self._pumps}
        return s

    def _drain(self, q: queue.Queue, limit: int, timeout_s: float = 0.0) -> list[Any]:
        items = []
        try:
            items.append(q.get(timeout=timeout_s) if timeout_s else q.get_nowait())
            while len(items) < limit:
                items.append(q.get_nowait())
        except queue.Empty:
            pass
        return items

    def _write_loop(self) -> None:
        writer = self._writer
        last_flush = time.monotonic()
        try:
            while True:
                pumps_done = self._stop.is_set() and not any(p.is_alive() for p in self._pumps)
                frames = self._drain(self._frames, _FRAME_BATCH, 0.0 if pumps_done else 0.02)
                forces = self._drain(self._forces, 1 << 20)
                control = self._drain(self._control, 1 << 20)
                frames = self._within_duration(frames)
                if self._end_host_ns is not None:
                    forces = [f for f in forces if f.t_host_ns < self._end_host_ns]
                if frames:
                    self._frame_t_host[1] = frames[-1].t_host_ns
                    self._frame_t_device.extend(fr.t_device_ns for fr in frames)
                writer.append_frames(frames)
                writer.append_forces(forces)
                for message in control:
                    if message[0] == "event":
                        writer.append_events([message[1]])
                    else:
                        writer.add_gap(*message[1:])
                if time.monotonic() - last_flush >= self.flush_interval_s:
                    self._flush()
                    last_flush = time.monotonic()
                if pumps_done and not (frames or forces or control):
                    break
            writer.close()
        except Exception as exc:  # handed to stop(), which reports it
            self._error = exc
            self._stop.set()
            writer.abort()

    def _within_duration(self, frames: list[StereoFrame]) -> list[StereoFrame]:
        """The frames that fall inside the requested duration (a faster-than-real-time
        simulation may deliver many frames per progress tick)."""
        if frames and not self._frame_t_device:
            self._frame_t_host[0] = frames[0].t_host_ns
        if self._span_limit_ns is None or not (frames or self._frame_t_device):
            return frames
        self._end_host_ns = self._frame_t_host[0] + self._span_limit_ns
        kept = [fr for fr in frames if fr.t_host_ns < self._end_host_ns]
        if len(kept) < len(frames):
            self._span_reached.set()
        return kept

    def _reached_end_ns(self) -> int | None:
        """The recording's end (host ns) once the duration is reached, for the force reader."""
        return self._end_host_ns if self._span_reached.is_set() else None

    def _flush(self) -> None:
        self._writer.flush()
        free = free_bytes(self.path.parent)
        if free < self.min_free_bytes // 4:
            raise SessionError(f"disk almost full: {free / 1e9:.2f} GB left on {self.path.parent}")
        if self.on_flush is not None:
            self.on_flush(self._update_stats())

    def _final_attrs(self, stats: RecorderStats) -> dict[str, Any]:
        attrs: dict[str, Any] = {"end_reason": stats.end_reason}
        for pump in self._pumps:
            attrs[f"{pump.stream}_queue_dropped"] = pump.dropped
        for stream, device in (("camera", self.devices.camera), ("force", self.devices.trocar)):
            attrs[f"{stream}_device_dropped"] = int(device.stats.dropped)
            attrs[f"{stream}_device_malformed"] = int(device.stats.malformed)
        return attrs

    def _truth(self) -> dict[str, np.ndarray] | None:
        bench = self.devices.bench
        if bench is None or not self._frame_t_device:
            return None
        return bench.session_truth(np.array(self._frame_t_device, dtype=np.int64))
