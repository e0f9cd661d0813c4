"""The recorder: per-device reader threads → bounded queues → one writer thread → HDF5.

For a real-time device a full queue never blocks it: the sample is dropped, counted and marked
as a gap. A device that describes itself as not real time (``describe()["realtime"] is False``,
the simulated bench run as fast as it renders) waits for room instead: the writer paces it.
Flushes (SWMR) are scheduled on the clock, every half ``flush_interval_s``, so the data lost
to a crash (flush time, queued samples and scheduling delays included) stays within it. Free
space is checked continuously (on the clock and by volume written); below a quarter of
``min_free_bytes`` the session stops and is finalized. A write failure (full disk,
I/O error) stops capture and leaves the file as of its last flush. A device that vanishes ends
the session cleanly with what was recorded and a marked gap. In :meth:`Recorder.run`, Ctrl-C
and SIGTERM stop the recording; further ones while it is being finished are ignored.
A recording of a given duration keeps exactly the frames and force samples that arrived (host
clock) before its end: when the duration is reached, the force reader goes on until it has read
past the end, so which samples are kept never depends on when the threads happened to stop.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import re
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vbfe.acquire.errors import SessionError
from vbfe.acquire.recording.storage import check_destination, free_bytes
from vbfe.acquire.session.writer import SessionWriter, finalize_session
from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.errors import DeviceError
from vbfe.drivers.registry import Devices
from vbfe.drivers.samples import ForceSample, ProjectorEvent, StereoFrame
from vbfe.drivers.trocar.base import ForceSensor

_READ_TIMEOUT_S = 0.2
_FRAME_BATCH = 1  # frames appended between two looks at the flush schedule
_PUT_POLL_S = 0.1  # a paced device rechecks the stop flag this often while the queue is full
_SPACE_CHECK_S = 0.25  # free space is read this often, and after every eighth of the stop
# margin (a quarter of min_free_bytes) written, however fast the frames come
_MIN_SPACE_CHECK_BYTES = 1 << 20
_FINALIZE_MIN_FREE_BYTES = 1 << 20  # after a failed write, finalize only with this much room

PatternSource = np.ndarray | Callable[[int, int], np.ndarray]
_END_GRACE_S = 2.0  # how long a reader may go on after the stop to reach the recording's end


@dataclass
class RecorderStats:
    """Progress of a recording, as shown on the progress line."""

    elapsed_s: float = 0.0  # span of recorded frame host times
    first_frame_host_ns: int = 0  # host time of the first recorded frame
    newest_read_host_ns: int = 0  # host time of the newest frame read from the camera
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

    def __init__(self, name: str, device: StereoCamera | ForceSensor, out: queue.Queue,
                 control: queue.Queue, stop: threading.Event, paced: bool = False,
                 read_until_ns: Callable[[], int | None] = lambda: None) -> None:
        super().__init__(name=f"vbfe-read-{name}", daemon=True)
        self.stream, self._device, self._out = name, device, out
        self._control, self._halt = control, stop
        self.paced = paced
        self._read_until_ns = read_until_ns
        self.dropped = 0
        self.last_seq = -1
        self.last_t_host_ns = 0  # host time of the newest item read
        self.error: str | None = None
        self._halted_at: float | None = None

    def _done(self) -> bool:
        """Stopped, and past the recording's end (``read_until_ns``) when there is one."""
        if not self._halt.is_set():
            return False
        end_ns = self._read_until_ns()
        if end_ns is None or self.last_t_host_ns >= end_ns:
            return True
        if self._halted_at is None:
            self._halted_at = time.monotonic()
        return time.monotonic() - self._halted_at > _END_GRACE_S

    def run(self) -> None:
        burst = 0
        while not self._done():
            try:
                item = self._device.read(_READ_TIMEOUT_S)
            except DeviceError as exc:
                self.error = str(exc)
                self._control.put(("gap", self.stream, "device disconnected", self.last_seq, -1,
                                   time.monotonic_ns(), 0))
                break
            for mark in self._device.stats.take_marks():  # bus errors the device reported
                self._control.put(("gap", self.stream, mark.reason, mark.last_seq, mark.next_seq,
                                   mark.t_host_ns, mark.count))
            if item is None:
                continue
            self.last_t_host_ns = item.t_host_ns
            try:
                if self.paced:
                    self._put_paced(item)
                    continue
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

    def _put_paced(self, item: Any) -> None:
        """Wait for room in the queue (the device is not real time: it waits, nothing drops;
        after a stop, only while the reader still has to reach the recording's end)."""
        while True:
            try:
                self._out.put(item, timeout=_PUT_POLL_S)
            except queue.Full:
                if self._done():
                    return
                continue
            self.last_seq = item.seq
            return


def _is_write_failure(exc: BaseException) -> bool:
    """An expected failure of the file (h5py raises RuntimeError for some failed flushes)."""
    return isinstance(exc, (OSError, SessionError)) or (
        isinstance(exc, RuntimeError) and "errno =" in str(exc))


def _failure_reason(exc: BaseException) -> str:
    """A short reason for a failed write (HDF5 messages embed errno and buffer addresses)."""
    errno = getattr(exc, "errno", None)
    if not errno:
        found = re.search(r"errno = (\d+)", str(exc))
        errno = int(found.group(1)) if found else None
    return os.strerror(errno) if errno else str(exc)[:200]


class Recorder:
    """Record a camera, a force sensor and a projector into one session file.

    Use as ``with Recorder(devices, path) as rec: rec.run(duration_s)`` or call
    :meth:`start` / :meth:`stop` yourself. Devices are opened and closed by the recorder.
    ``pattern`` is the image to project, or a function of the opened projector's
    ``(width, height)`` that makes it.
    """

    def __init__(self, devices: Devices, path: str | Path, compression: str = "lzf",
                 flush_interval_s: float = 1.0, metadata: dict[str, Any] | None = None,
                 calibration_yaml: str | None = None, queue_size: int = 256,
                 min_free_bytes: int = 1 << 30, pattern: PatternSource | None = None,
                 pattern_name: str = "debruijn",
                 on_flush: Callable[[RecorderStats], None] | None = None,
                 overwrite: bool = False,
                 on_forces: Callable[[list[ForceSample]], None] | None = None) -> None:
        if flush_interval_s <= 0:
            raise SessionError(f"flush_interval_s must be positive, got {flush_interval_s}")
        self.devices = devices
        self.path = check_destination(path, min_free_bytes, overwrite)
        self.compression = compression
        self.flush_interval_s = flush_interval_s
        self.metadata = dict(metadata or {})
        self.calibration_yaml = calibration_yaml
        self.min_free_bytes = min_free_bytes
        self.pattern, self.pattern_name = pattern, pattern_name
        self.on_flush = on_flush
        self.on_forces = on_forces  # sees every batch of force samples (writer thread)
        self._frames: queue.Queue = queue.Queue(maxsize=queue_size)
        self._forces: queue.Queue = queue.Queue(maxsize=queue_size * 64)
        self._control: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._pumps: list[_Pump] = []
        self._writer_thread: threading.Thread | None = None
        self._writer: SessionWriter | None = None
        self._error: BaseException | None = None
        self._fault: str | None = None  # a reason to stop that is reported after finalizing
        self._closed_after_error = False
        self._stop_request: str | None = None  # set by Ctrl-C / SIGTERM during run()
        self._flush_cost_s = 0.0  # longest recent flush
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
        described = {"camera": cam.describe(), "trocar": trocar.describe(),
                     "projector": projector.describe()}
        self.metadata.setdefault("devices", described)
        paced = described["camera"].get("realtime") is False
        pattern = self.pattern
        if callable(pattern):  # sized now that the projector is open (an HDMI screen's size)
            try:
                pattern = pattern(projector.width, projector.height)
            except Exception:
                self._close_devices()
                raise
            self.pattern = pattern  # the image shown (a sync protocol flashes it)
        try:  # refused while another process writes the file, or cannot be created
            self._writer = SessionWriter(self.path, (cam.width, cam.height), self.compression,
                                         self.metadata, self.calibration_yaml,
                                         getattr(trocar, "axes", ("x", "y", "z")),
                                         self.flush_interval_s)
        except BaseException:
            self._close_devices()
            raise
        self._t_start = time.monotonic()
        if pattern is not None:
            try:
                self._control.put(("event", projector.show(pattern, self.pattern_name)))
            except DeviceError:
                self._writer.abort()
                self._close_devices()
                raise
        self._pumps = [_Pump("camera", cam, self._frames, self._control, self._stop, paced),
                       _Pump("force", trocar, self._forces, self._control, self._stop, paced,
                             self._reached_end_ns)]
        self._writer_thread = threading.Thread(target=self._write_loop, name="vbfe-writer",
                                               daemon=True)
        self._writer_thread.start()
        for pump in self._pumps:
            pump.start()

    def show(self, pattern: np.ndarray, name: str) -> ProjectorEvent:
        """Put ``pattern`` on the projector now and record the event (call from the thread
        that runs :meth:`run`, e.g. from its ``on_tick``)."""
        event = self.devices.projector.show(pattern, name)
        self._control.put(("event", event))
        return event

    def run(self, duration_s: float | None = None,
            on_progress: Callable[[RecorderStats], None] | None = None,
            progress_interval_s: float = 0.5,
            on_tick: Callable[["Recorder", RecorderStats], None] | None = None) -> RecorderStats:
        """Record until ``duration_s`` of frames (host clock) are in, a device is gone, the
        disk is almost full, Ctrl-C or SIGTERM; then stop cleanly. ``on_tick`` is called every
        50 ms (wall clock) with the current statistics. Returns the final statistics."""
        last_progress = 0.0
        if duration_s is not None:
            if not duration_s > 0:
                self.stop()
                raise SessionError(f"the duration must be positive, got {duration_s} s")
            self._span_limit_ns = int(duration_s * 1e9)
        with self._signals_stop():
            while not self._stop.is_set() and self._stop_request is None:
                time.sleep(0.05)
                stats = self._update_stats()
                if on_tick is not None:
                    on_tick(self, stats)
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
            if self._stop_request is not None:
                self.stats.end_reason = self._stop_request
            return self.stop()

    @contextlib.contextmanager
    def _signals_stop(self):
        """While recording, Ctrl-C and SIGTERM ask the loop to stop; once stopping, they are
        ignored with a message (only in the main thread, where Python handles signals)."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return

        def on_signal(signum: int, frame: Any) -> None:
            if self._stop_request is None and not self._stop.is_set():
                self._stop_request = ("stopped by operator" if signum == signal.SIGINT
                                      else f"stopped by {signal.Signals(signum).name}")
            else:
                print(f"vbfe: finishing {self.path}, please wait (Ctrl-C is ignored until it "
                      "is closed)", file=sys.stderr, flush=True)

        previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def request_stop(self, reason: str) -> None:
        """Ask a running :meth:`run` (e.g. in another thread) to stop cleanly with ``reason``."""
        if self._stop_request is None:
            self._stop_request = reason

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
            if not _is_write_failure(self._error):
                raise self._error  # a bug: keep its traceback
            reason = _failure_reason(self._error)
            if self._closed_after_error and free_bytes(self.path.parent) > _FINALIZE_MIN_FREE_BYTES:
                with contextlib.suppress(SessionError, OSError, RuntimeError):
                    finalize_session(self.path, self._final_attrs(stats, f"write failed: {reason}"))
            raise SessionError(f"writing {self.path} failed ({reason}); recording stopped, the "
                               "file keeps what was written before the failure (see `vbfe "
                               f"inspect {self.path}`)") from None
        if not stats.end_reason:
            stats.end_reason = self._fault or "stopped"
        finalize_session(self.path, self._final_attrs(stats), self._truth())
        if self._fault is not None:
            raise SessionError(f"{self._fault}; recording stopped and {self.path} finalized with "
                               f"{stats.frames} frames")
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
        s.first_frame_host_ns = self._frame_t_host[0]
        s.newest_read_host_ns = max((p.last_t_host_ns for p in self._pumps
                                     if p.stream == "camera"), default=0)
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

    def _flush_period_s(self) -> float:
        """Time between flush starts. A crash loses at most one period plus the flush itself,
        the samples still queued and any delay of the writer under load: flushes start every
        half interval (sooner when they are slow), leaving the other half for the rest."""
        interval = self.flush_interval_s
        return max(interval / 4, interval / 2 - self._flush_cost_s)

    def _write_loop(self) -> None:
        writer = self._writer
        next_flush = time.monotonic() + self._flush_period_s()
        next_space_check = 0.0
        check_every_bytes = max(self.min_free_bytes // 32, _MIN_SPACE_CHECK_BYTES)
        checked_at_bytes = 0
        try:
            while True:
                pumps_done = self._stop.is_set() and not any(p.is_alive() for p in self._pumps)
                frames = self._drain(self._frames, _FRAME_BATCH, 0.0 if pumps_done else 0.02)
                forces = self._drain(self._forces, 1 << 20)
                if forces and self.on_forces is not None:
                    self.on_forces(forces)
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
                now = time.monotonic()
                if now >= next_flush:  # on the clock: a slow flush does not shift the next one
                    self._flush()
                    next_flush += self._flush_period_s()
                    if next_flush <= time.monotonic():
                        next_flush = time.monotonic()
                if (now >= next_space_check
                        or writer.bytes_written - checked_at_bytes >= check_every_bytes):
                    self._check_space()
                    next_space_check, checked_at_bytes = now + _SPACE_CHECK_S, writer.bytes_written
                if pumps_done and not (frames or forces or control):
                    break
            writer.close()
        except Exception as exc:  # handed to stop(), which reports it
            self._error = exc
            self._stop.set()
            self._closed_after_error = writer.abort()

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
        started = time.monotonic()
        self._writer.flush()
        cost = time.monotonic() - started
        self._flush_cost_s = max(cost, 0.9 * self._flush_cost_s)  # slow flushes count for a while
        if self.on_flush is not None:
            self.on_flush(self._update_stats())

    def _check_space(self) -> None:
        """Stop (the session is then finalized) when free space falls below a quarter of
        ``min_free_bytes``."""
        free = free_bytes(self.path.parent)
        if free < self.min_free_bytes // 4 and self._fault is None:
            self._fault = (f"disk almost full: {free / 1e9:.3f} GB left on {self.path.parent} "
                           f"(limit {self.min_free_bytes / 4e9:.3f} GB, a quarter of min_free_gb)")
            self._stop.set()

    def _final_attrs(self, stats: RecorderStats, end_reason: str | None = None) -> dict[str, Any]:
        attrs: dict[str, Any] = {"end_reason": end_reason or stats.end_reason}
        for pump in self._pumps:
            attrs[f"{pump.stream}_queue_dropped"] = pump.dropped
        for stream, device in (("camera", self.devices.camera), ("force", self.devices.trocar)):
            attrs[f"{stream}_device_dropped"] = int(device.stats.dropped)
            attrs[f"{stream}_device_malformed"] = int(device.stats.malformed)
            attrs[f"{stream}_device_errors"] = int(device.stats.errors)
        attrs["devices_at_end_json"] = json.dumps(  # e.g. the trocar's clock, decided at frame 1
            {"camera": self.devices.camera.describe(), "trocar": self.devices.trocar.describe()},
            default=str)
        return attrs

    def _truth(self) -> dict[str, np.ndarray] | None:
        bench = self.devices.bench
        if bench is None or not self._frame_t_device:
            return None
        return bench.session_truth(np.array(self._frame_t_device, dtype=np.int64))
