"""The session sink: the listener that writes an acquisition into one session file.

Flushes (SWMR) are scheduled on the clock, every half ``flush_interval_s``, so the data lost to
a crash (flush time, queued records and scheduling delays included) stays within it. Free space
is checked continuously (on the clock and by volume written); below a quarter of
``min_free_bytes`` the acquisition is halted and the session finalized. A write failure (full
disk, I/O error) halts it and leaves the file as of its last flush. A writer that falls
behind (its frame queue an eighth full) stores the frames with the least CPU the compression
allows until it has caught up, its queue empty (``gzip``: uncompressed deflate blocks;
counted in the file's ``camera_frames_stored``), so that a machine short of CPU costs file
size, not frames. At the end the file is
finalized with the drop counters, the devices' final description and, on a simulated rig, the
per-frame ground truth.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vbfe.acquire.recording.listener import Gap, Listener
from vbfe.acquire.recording.storage import check_destination, free_bytes
from vbfe.acquire.session.extra_streams import MARKS, lsl_stream_spec
from vbfe.acquire.session.layout import CAMERA, DEFAULT_COMPRESSION, STREAMS, StreamSpec
from vbfe.acquire.session.writer import SessionWriter, finalize_session
from vbfe.common.errors import SessionError
from vbfe.common.logs import LogLines
from vbfe.drivers.streams.records import StreamInfo

if TYPE_CHECKING:
    from vbfe.acquire.recording.acquisition import Acquisition, AcquisitionStats

log = logging.getLogger(__name__)

_SPACE_CHECK_S = 0.25  # free space is read this often, and after every eighth of the stop
# margin (a quarter of min_free_bytes) written, however fast the frames come
_MIN_SPACE_CHECK_BYTES = 1 << 20
_FINALIZE_MIN_FREE_BYTES = 1 << 20  # after a failed write, finalize only with this much room
_BEHIND = 0.125  # camera queue this full: frames are stored with the least CPU until it is empty


def _is_write_failure(exc: BaseException) -> bool:
    """An expected failure of the file (h5py raises RuntimeError for some failed flushes)."""
    return isinstance(exc, (OSError, SessionError)) or (
        isinstance(exc, RuntimeError) and "errno =" in str(exc)
    )


def _failure_reason(exc: BaseException) -> str:
    """A short reason for a failed write (HDF5 messages embed errno and buffer addresses)."""
    errno = getattr(exc, "errno", None)
    if not errno:
        found = re.search(r"errno = (\d+)", str(exc))
        errno = int(found.group(1)) if found else None
    return os.strerror(errno) if errno else str(exc)[:200]


def _merged_metadata(given: dict[str, Any], described: dict[str, Any]) -> dict[str, Any]:
    """The session metadata: what the command gave over what the rig describes (its devices
    and backend facts such as a simulated trial's conditions; dicts merged, given keys win)."""
    out = dict(given)
    for key, value in described.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**value, **out[key]}
        else:
            out.setdefault(key, value)
    return out


@dataclass(frozen=True)
class Mark:
    """An event mark (``vbfe mark``): its text and host time."""

    text: str
    seq: int
    t_device_ns: int  # the marks stream's clock is the host's
    t_host_ns: int


class SessionSink(Listener):
    """Write every record of an acquisition into the new session file ``path``.

    ``streams`` are the specs of streams beyond the core ones (camera, force, projector) that
    the rig's further devices feed, or :meth:`post` from any thread; the rig's LSL streams
    (devices with an ``info``) are added when it starts. With a :func:`marks_stream` among
    them, :meth:`mark` puts event marks into the session from any thread.
    ``on_flush(stats)`` is called after each flush (dispatch thread). The destination is
    checked (folder, free space, ``overwrite``) when the sink is made.
    """

    def __init__(
        self,
        path: str | Path,
        compression: str = DEFAULT_COMPRESSION,
        flush_interval_s: float = 1.0,
        metadata: dict[str, Any] | None = None,
        calibration_yaml: str | None = None,
        min_free_bytes: int = 1 << 30,
        overwrite: bool = False,
        on_flush: Callable[[AcquisitionStats], None] | None = None,
        streams: Sequence[StreamSpec] = (),
    ) -> None:
        if flush_interval_s <= 0:
            raise SessionError(f"flush_interval_s must be positive, got {flush_interval_s}")
        self.path = check_destination(path, min_free_bytes, overwrite)
        self.compression = compression
        self.flush_interval_s = flush_interval_s
        self.metadata = dict(metadata or {})
        self.calibration_yaml = calibration_yaml
        self.min_free_bytes = min_free_bytes
        self.on_flush = on_flush
        self.streams = tuple(streams)
        self._acquisition: Acquisition  # from on_start, before any record
        self._writer: SessionWriter  # from on_start
        self._error: BaseException | None = None
        self._fault: str | None = None  # a reason to stop, reported after finalizing
        self._flush_cost_s = 0.0  # longest recent flush
        self._behind = False  # storing frames with the least CPU until the queue is empty
        self._next_flush = self._next_space_check = 0.0
        self._checked_at_bytes = 0
        self._frame_t_device: list[int] = []
        self._marks = 0
        self._posted: list[tuple[str, Sequence[Any]]] = []
        self._posted_lock = threading.Lock()
        self.log = LogLines()  # the recording's log lines, kept in the session

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """Note a failure of the file (then re-raised: it stops the acquisition)."""
        try:
            yield
        except Exception as exc:
            self._error = exc
            raise

    # -- listener hooks -------------------------------------------------------------------
    def on_start(self, acquisition: Acquisition) -> None:
        rig = acquisition.rig
        self._acquisition = acquisition
        self.streams += tuple(
            lsl_stream_spec(device.info)
            for _, device in rig.streams()
            if isinstance(getattr(device, "info", None), StreamInfo)
        )
        known = {*STREAMS, *(spec.name for spec in self.streams)}
        missing = sorted(stream for stream, _ in rig.streams() if stream not in known)
        if missing:
            raise SessionError(
                f"the rig's streams {missing} have no session stream to go to; "
                "give their specs to the recorder (streams=...)"
            )
        self.metadata = _merged_metadata(self.metadata, rig.describe())
        self._writer = SessionWriter(
            self.path,
            (rig.camera.width, rig.camera.height),
            self.compression,
            self.metadata,
            self.calibration_yaml,
            rig.trocar.axes,
            self.flush_interval_s,
            self.streams,
        )
        self._next_flush = time.monotonic() + self._flush_period_s()

    def on_records(self, stream: str, records: Sequence[Any]) -> None:
        if self._fault is not None:  # halted for space: what is still queued is not written
            return
        with self._writing():
            # a backlog of frames comes in one call: written a few at a time, the free space
            # read between them, so it cannot outrun the stop margin
            step = len(records)
            if stream == CAMERA:
                camera = self._acquisition.rig.camera
                pair_bytes = 6 * camera.width * camera.height  # uncompressed: the most it takes
                step = max(1, self._check_every() // pair_bytes)
            for start in range(0, len(records), step):
                part = records[start : start + step]
                if stream == CAMERA:
                    self._frame_t_device.extend(fr.t_device_ns for fr in part)
                    waiting = len(records) - start - len(part)
                    for frames, behind in self._by_backlog(part, waiting):
                        self._writer.append(CAMERA, frames, behind)
                else:
                    self._writer.append(stream, part)
                if self._writer.bytes_written - self._checked_at_bytes >= self._check_every():
                    self._check_space()
                    if self._fault is not None:
                        return

    def _by_backlog(self, frames: Sequence[Any], waiting: int) -> list[tuple[list[Any], bool]]:
        """``frames`` in runs of those stored with the least CPU (the writer behind: from an
        eighth of the queue waiting after a frame, ``waiting`` more of this batch included,
        until none waits) and of those compressed."""
        runs: list[tuple[list[Any], bool]] = []
        for k, frame in enumerate(frames):
            backlog = self._acquisition.backlog(len(frames) - k - 1 + waiting)
            self._behind = backlog >= _BEHIND or (self._behind and backlog > 0)
            if runs and runs[-1][1] == self._behind:
                runs[-1][0].append(frame)
            else:
                runs.append(([frame], self._behind))
        return runs

    def on_gap(self, gap: Gap) -> None:
        with self._writing():
            self._writer.add_gap(
                gap.stream, gap.reason, gap.last_seq, gap.next_seq, gap.t_host_ns, gap.count
            )

    def add_stream(self, spec: StreamSpec) -> None:
        """One more stream to record, fed by :meth:`post` (before the acquisition starts).

        :raises SessionError: the session file is made already."""
        if hasattr(self, "_writer"):
            raise SessionError(f"{self.path} is being recorded: streams are added before")
        self.streams += (spec,)

    def post(self, stream: str, records: Sequence[Any]) -> None:
        """Records of one of ``streams`` from any thread: written by the dispatch thread within
        a round, flushed with the frames (posted after the stop: not written).

        :raises SessionError: the session has no such stream."""
        if stream not in (spec.name for spec in self.streams):
            raise SessionError(f"{self.path} records no stream {stream!r}")
        with self._posted_lock:
            self._posted.append((stream, records))

    def mark(self, text: str, t_host_ns: int) -> None:
        """Put an event mark at host time ``t_host_ns`` into the session (any thread).

        :raises SessionError: the session records no event marks."""
        if MARKS not in (spec.name for spec in self.streams):
            raise SessionError(f"{self.path} records no event marks (no {MARKS!r} stream)")
        with self._posted_lock:
            self._marks += 1
            self._posted.append((MARKS, [Mark(text, self._marks - 1, t_host_ns, t_host_ns)]))

    def _write_posted(self) -> None:
        with self._posted_lock:
            posted, self._posted = self._posted, []
        for stream, records in posted:
            self._writer.append(stream, records)

    def on_round(self) -> None:
        writer, stats = self._writer, self._acquisition.stats
        with self._writing():
            self._write_posted()
            writer.append_log(self.log.take())
            now = time.monotonic()
            if now >= self._next_flush:  # on the clock: a slow flush does not shift the next
                self._flush()
                self._next_flush += self._flush_period_s()
                if self._next_flush <= time.monotonic():
                    self._next_flush = time.monotonic()
            if now >= self._next_space_check:
                self._check_space()
        stats.bytes_written = writer.bytes_written

    def on_stop(self, acquisition: Acquisition) -> None:
        try:
            self._stop(acquisition)
        finally:
            self.log.detach()

    def _stop(self, acquisition: Acquisition) -> None:
        writer, stats = self._writer, acquisition.stats
        if writer.frames_stored:
            log.warning(
                "%d of %d frames stored uncompressed: the writer was behind (short of CPU)",
                writer.frames_stored,
                writer.counts[CAMERA],
            )
        if self._error is None:
            with contextlib.suppress(Exception), self._writing():
                self._write_posted()
                writer.append_log(self.log.take())
                writer.close()
        stats.flushed, stats.bytes_written = dict(writer.flushed_counts), writer.bytes_written
        if self._error is not None:
            closed = writer.abort()
            if not _is_write_failure(self._error):
                raise self._error  # a bug: keep its traceback
            reason = _failure_reason(self._error)
            if closed and free_bytes(self.path.parent) > _FINALIZE_MIN_FREE_BYTES:
                with contextlib.suppress(SessionError, OSError, RuntimeError):
                    finalize_session(
                        self.path,
                        self._final_attrs(acquisition, f"write failed: {reason}"),
                        log_lines=self.log,
                    )
            raise SessionError(
                f"writing {self.path} failed ({reason}); recording stopped, the "
                "file keeps what was written before the failure (see `vbfe "
                f"inspect {self.path}`)"
            ) from None
        finalize_session(
            self.path, self._final_attrs(acquisition), self._truth(acquisition), self.log
        )
        if self._fault is not None:
            raise SessionError(
                f"{self._fault}; recording stopped and {self.path} finalized with "
                f"{writer.counts[CAMERA]} frames"
            )

    # -- internals ------------------------------------------------------------------------
    def _flush_period_s(self) -> float:
        """Time between flush starts. A crash loses at most one period plus the flush itself,
        the records still queued and any delay of the dispatch under load: flushes start every
        half interval (sooner when they are slow), leaving the other half for the rest."""
        interval = self.flush_interval_s
        return max(interval / 4, interval / 2 - self._flush_cost_s)

    def _flush(self) -> None:
        started = time.monotonic()
        self._writer.flush()
        cost = time.monotonic() - started
        self._flush_cost_s = max(cost, 0.9 * self._flush_cost_s)  # slow flushes count for a while
        stats = self._acquisition.update_stats()
        stats.flushed, stats.bytes_written = (
            dict(self._writer.flushed_counts),
            self._writer.bytes_written,
        )
        if self.on_flush is not None:
            self.on_flush(stats)

    def _check_every(self) -> int:
        """Bytes written between two reads of the free space: an eighth of the stop margin."""
        return max(self.min_free_bytes // 32, _MIN_SPACE_CHECK_BYTES)

    def _check_space(self) -> None:
        """Halt the acquisition (the session is then finalized) when free space falls below a
        quarter of ``min_free_bytes``."""
        self._next_space_check = time.monotonic() + _SPACE_CHECK_S
        self._checked_at_bytes = self._writer.bytes_written
        free = free_bytes(self.path.parent)
        if free < self.min_free_bytes // 4 and self._fault is None:
            self._fault = (
                f"disk almost full: {free / 1e9:.3f} GB left on {self.path.parent} "
                f"(limit {self.min_free_bytes / 4e9:.3f} GB, a quarter of min_free_gb)"
            )
            self._acquisition.halt(self._fault)

    def _final_attrs(
        self, acquisition: Acquisition, end_reason: str | None = None
    ) -> dict[str, Any]:
        stats = acquisition.stats
        attrs: dict[str, Any] = {
            "end_reason": end_reason or stats.end_reason,
            "camera_frames_stored": self._writer.frames_stored,
        }
        readers = dict(acquisition.rig.streams())
        for stream, device in readers.items():
            attrs[f"{stream}_queue_dropped"] = stats.queue_dropped.get(stream, 0)
            attrs[f"{stream}_device_dropped"] = int(device.stats.dropped)
            attrs[f"{stream}_device_malformed"] = int(device.stats.malformed)
            attrs[f"{stream}_device_errors"] = int(device.stats.errors)
        attrs["devices_at_end_json"] = json.dumps(  # e.g. the trocar's clock, decided at frame 1
            {
                name: d.describe()
                for name, d in acquisition.rig.devices.items()
                if d.stream is not None
            },
            default=str,
        )
        return attrs

    def _truth(self, acquisition: Acquisition) -> dict[str, np.ndarray] | None:
        truth = acquisition.rig.truth
        if truth is None or not self._frame_t_device:
            return None
        return truth.session_truth(np.array(self._frame_t_device, dtype=np.int64))
