"""Low-level session writer: creates the layout's streams, appends records, flushes in SWMR mode.

Every dataset is resizable, chunked and Fletcher-32 checksummed, and the file is switched to
SWMR mode once the layout exists, so a flushed file stays readable whatever happens to the
writing process afterwards. :func:`finalize_session` runs after a clean close: it adds the clock
fits, end attributes and (for simulated sessions) the ground truth, which SWMR mode does not
allow adding earlier. It reopens the file without HDF5's file lock, so readers that have the
session open (SWMR readers, which never modify it) cannot stop it.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import logging
import os
import shutil
import socket
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import h5py
import numpy as np

from vbfe.acquire.session.clock import fit_clock
from vbfe.acquire.session.layout import (
    CAMERA,
    COMPRESSIONS,
    DEFAULT_COMPRESSION,
    EXTRA_STREAMS_ATTR,
    FORCE,
    GAP_COLUMNS,
    GAP_REASONS,
    IMAGE_CODECS,
    JPEG_QUALITY,
    LOG,
    PROJECTOR,
    SCHEMA_VERSION,
    TIME_COLUMNS,
    StreamSpec,
    core_streams,
    image_filter,
    session_streams,
)
from vbfe.acquire.session.reader import consistent_rows
from vbfe.common.errors import SessionError
from vbfe.common.files import SESSION_FORMAT, WriterLock, create_hdf5
from vbfe.common.logs import LINE_FORMAT, LogLines
from vbfe.common.version import __version__
from vbfe.drivers.samples import ForceSample, ProjectorEvent, StereoFrame

log = logging.getLogger(__name__)

_JPEG_CHUNK = 1 << 20
RESERVE_BYTES = 16 << 20  # held back so HDF5 can still write out its caches after a full disk
# no chunk cache for images: a frame is compressed and written as it is appended, so a flush
# has only metadata and the small time series left to write
_IMAGE_CACHE = {"rdcc_nbytes": 0, "rdcc_w0": 1.0}


def _reserve_space(directory: Path) -> int | None:
    """Hold free space in an unlinked file (the kernel frees it when the descriptor closes,
    also on SIGKILL); returns the descriptor, or None where nothing could be reserved."""
    try:
        fd, name = tempfile.mkstemp(dir=directory, prefix=".vbfe-reserve-")
    except OSError:
        return None
    os.unlink(name)
    with contextlib.suppress(OSError):
        os.posix_fallocate(fd, 0, min(RESERVE_BYTES, shutil.disk_usage(directory).free // 8))
    return fd


def _series(
    group: h5py.Group,
    name: str,
    dtype: Any,
    shape: tuple[int, ...] = (),
    chunk: int = 4096,
    **kwargs: Any,
) -> h5py.Dataset:
    """A resizable, chunked dataset of rows of ``shape``; checksummed unless it holds text
    (HDF5 filters cannot apply to variable-length data)."""
    checksum = h5py.check_string_dtype(np.dtype(dtype)) is None
    return group.create_dataset(
        name,
        shape=(0, *shape),
        maxshape=(None, *shape),
        chunks=(chunk, *shape),
        dtype=dtype,
        fletcher32=checksum,
        **kwargs,
    )


def _append(ds: h5py.Dataset, values: np.ndarray) -> None:
    n = ds.shape[0]
    ds.resize(n + len(values), axis=0)
    ds[n:] = values


def _encode_jpeg(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise SessionError("OpenCV could not JPEG-encode a frame for the mjpeg compression")
    return buf.tobytes()


class SessionWriter:
    """Writes one session file: the core streams and ``extra_streams``; call the ``append*``
    methods from a single thread, :meth:`flush` now and then, and :meth:`close` at the end
    (then :func:`finalize_session` marks the file complete). The file is in SWMR mode once
    created, so readers may open it while it is written.

    :param path: the session file to create (an existing one is replaced: callers check
        :func:`vbfe.common.files.check_outputs` first).
    :param frame_size: ``(width, height)`` of one eye's images.
    :param compression: how images are stored: one of ``COMPRESSIONS`` of the session layout
        (``"mjpeg"`` keeps JPEG bytes, the others compress raw pixels).
    :param metadata: JSON-able facts about the recording (operator, notes, protocol, ...).
    :param calibration_yaml: the stereo calibration to store with the session (OpenCV YAML).
    :param force_axes: names of the force columns.
    :param flush_interval_s: the recorder's flush interval, stored for readers.
    :param extra_streams: specs of further streams (e.g. LSL streams, event marks).
    :raises SessionError: an unknown compression, stream names that clash, or a file that
        cannot be created.
    :raises OutputError: another process is writing the same file.
    """

    def __init__(
        self,
        path: str | Path,
        frame_size: tuple[int, int],
        compression: str = DEFAULT_COMPRESSION,
        metadata: dict[str, Any] | None = None,
        calibration_yaml: str | None = None,
        force_axes: Sequence[str] = ("x", "y", "z"),
        flush_interval_s: float = 1.0,
        extra_streams: Sequence[StreamSpec] = (),
    ) -> None:
        if compression not in COMPRESSIONS:
            raise SessionError(
                f"unknown compression {compression!r} for {path}; choose one of {COMPRESSIONS}"
            )
        self.path = Path(path)
        self.compression = compression
        self.bytes_written = 0  # uncompressed payload bytes
        self.frames_stored = 0  # frames stored uncompressed because the writer was behind
        encoding = "jpeg" if compression == "mjpeg" else "raw"
        specs = (*core_streams(frame_size, encoding, force_axes), *extra_streams)
        self.streams: dict[str, StreamSpec] = {spec.name: spec for spec in specs}
        if len(self.streams) < len(specs) or set(self.streams) & {
            "gaps",
            "clock_pairs",
            "clock",
            "truth",
            LOG,
        }:
            raise SessionError(
                f"stream names for {path} must be unique and not a session "
                f"dataset's: {[spec.name for spec in specs]}"
            )
        metadata = dict(metadata or {})
        self._lock = WriterLock(self.path).acquire()  # before the old file is truncated
        self._reserve = _reserve_space(self.path.parent)
        try:
            self._file = create_hdf5(self.path)
        except OSError as exc:
            self._release_reserve()
            raise SessionError(f"cannot create session file {self.path}: {exc}") from None
        f = self._file
        f.attrs.update(
            {
                "format": SESSION_FORMAT,
                "schema_version": SCHEMA_VERSION,
                "software_version": __version__,
                "compression": compression,
                "operator": str(metadata.get("operator", "")),
                "notes": str(metadata.get("notes", "")),
                "start_utc_ns": time.time_ns(),
                "start_host_ns": time.monotonic_ns(),
                "metadata_json": json.dumps(metadata, default=str),
                "complete": False,
                "flush_interval_s": float(flush_interval_s),
                "writer_host": socket.gethostname(),
                "writer_pid": os.getpid(),
            }
        )
        if extra_streams:
            f.attrs[EXTRA_STREAMS_ATTR] = json.dumps([spec.describe() for spec in extra_streams])
        self._data: dict[str, dict[str, h5py.Dataset]] = {}
        for spec in specs:
            self._data[spec.name] = self._create(f.create_group(spec.name), spec)
        f[CAMERA].attrs.update(
            {"width": frame_size[0], "height": frame_size[1], "encoding": encoding, "color": "BGR"}
        )
        self._gaps = _series(f, "gaps", np.int64, (len(GAP_COLUMNS),), 64)
        self._gaps.attrs.update(
            {
                "columns": list(GAP_COLUMNS),
                "streams": list(self.streams),
                "reasons": list(GAP_REASONS),
            }
        )
        self._wall = _series(f, "clock_pairs", np.int64, (2,), 64)
        self._wall.attrs["columns"] = ["t_utc_ns", "t_host_ns"]
        self._log = _series(f, LOG, h5py.string_dtype(), (), 256)
        self._log.attrs["format"] = LINE_FORMAT
        if calibration_yaml is not None:
            f.create_dataset("calibration_yaml", data=calibration_yaml, dtype=h5py.string_dtype())
        f.swmr_mode = True
        self.counts = {name: 0 for name in self.streams}
        self.flushed_counts = dict(self.counts)

    def _create(self, group: h5py.Group, spec: StreamSpec) -> dict[str, h5py.Dataset]:
        """The stream's datasets, as the layout table says."""
        data = {}
        for key in TIME_COLUMNS:
            data[key] = _series(group, key, np.int64, (), spec.chunk)
            if key != "seq":
                data[key].attrs["units"] = "ns"
        for column in spec.columns:
            extra = {**image_filter(self.compression), **_IMAGE_CACHE} if column.image else {}
            data[column.name] = _series(
                group, column.name, column.dtype, column.shape, column.chunk or spec.chunk, **extra
            )
            if column.units:
                data[column.name].attrs["units"] = column.units
            data[column.name].attrs.update(dict(column.attrs))
        for blob in spec.blobs:
            data[blob] = _series(group, blob, np.uint8, (), _JPEG_CHUNK)
        return data

    def append(self, stream: str, records: Sequence[Any], behind: bool = False) -> None:
        """Append records of a stream (data first, timestamps last, so a reader never sees a
        timestamp whose data is missing).

        :param stream: the stream's name.
        :param records: its records (with ``t_device_ns``, ``t_host_ns``, ``seq`` and the
            stream's columns as attributes).
        :param behind: the caller is falling behind: images are stored with the least CPU
            the compression allows (``gzip``: uncompressed deflate blocks, every reader
            reads them as before; counted in ``frames_stored``).
        :raises SessionError: the writer has no such stream.
        :raises OSError: the file cannot be written (e.g. the disk is full).
        """
        if not records:
            return
        spec = self.streams.get(stream)
        if spec is None:
            raise SessionError(
                f"{self.path} has no stream {stream!r} (streams: "
                f"{list(self.streams)}); give its spec to the writer"
            )
        if stream == CAMERA:
            self._append_images(records, behind)
        else:
            data = self._data[stream]
            for column in spec.columns:
                values = column.values(records)
                _append(data[column.name], values)
                if values.dtype != object:
                    self.bytes_written += values.nbytes
            self.bytes_written += 24 * len(records)  # the time columns
        data = self._data[stream]
        for key in TIME_COLUMNS:
            _append(data[key], np.array([getattr(r, key) for r in records], dtype=np.int64))
        self.counts[stream] += len(records)

    def _append_images(self, frames: Sequence[StereoFrame], behind: bool) -> None:
        data = self._data[CAMERA]
        if self.compression == "mjpeg":
            for i, eye in enumerate(("left", "right")):
                blobs = [
                    fr.encoded[i] if fr.encoded is not None else _encode_jpeg(getattr(fr, eye))
                    for fr in frames
                ]
                start = data[f"{eye}_jpeg"].shape[0]
                lengths = np.array([len(b) for b in blobs], dtype=np.int64)
                offsets = start + np.concatenate([[0], np.cumsum(lengths)[:-1]])
                _append(data[f"{eye}_jpeg"], np.frombuffer(b"".join(blobs), dtype=np.uint8))
                _append(data[f"{eye}_jpeg_index"], np.stack([offsets, lengths], axis=1))
                self.bytes_written += int(lengths.sum())
            return
        expected = data["left"].shape[1:]
        for fr in frames:
            if fr.left.shape != expected or fr.right.shape != expected:
                raise SessionError(
                    f"frame {fr.seq} for {self.path} is {fr.left.shape}, "
                    f"expected {expected} (did the camera change size?)"
                )
        write_row = IMAGE_CODECS[self.compression].write_row
        if behind and write_row is not None:
            self.frames_stored += len(frames)
        for eye in ("left", "right"):
            ds = data[eye]
            n = ds.shape[0]
            ds.resize(n + len(frames), axis=0)
            for k, fr in enumerate(frames):
                if write_row is None:
                    ds[n + k] = getattr(fr, eye)
                else:
                    write_row(ds, n + k, getattr(fr, eye), behind)
            self.bytes_written += len(frames) * fr.left.nbytes

    def append_frames(self, frames: Sequence[StereoFrame]) -> None:
        """Append stereo frames."""
        self.append(CAMERA, frames)

    def append_forces(self, samples: Sequence[ForceSample]) -> None:
        """Append force samples."""
        self.append(FORCE, samples)

    def append_events(self, events: Sequence[ProjectorEvent]) -> None:
        """Append projector events (pattern shown, frame ID)."""
        self.append(PROJECTOR, events)

    def add_gap(
        self, stream: str, reason: str, last_seq: int, next_seq: int, t_host_ns: int, count: int
    ) -> None:
        """Mark a gap in a stream: records lost between ``last_seq`` and ``next_seq``."""
        _append(
            self._gaps,
            np.array(
                [
                    [
                        list(self.streams).index(stream),
                        GAP_REASONS.index(reason),
                        last_seq,
                        next_seq,
                        t_host_ns,
                        count,
                    ]
                ],
                dtype=np.int64,
            ),
        )

    def append_log(self, lines: Sequence[str]) -> None:
        """Append log lines of the recording (see :class:`vbfe.common.logs.LogLines`)."""
        if lines:
            _append(self._log, np.array(lines, dtype=object))

    def flush(self, clock_pair: tuple[int, int] | None = None) -> dict[str, int]:
        """Make everything appended so far durable and visible to readers.

        :param clock_pair: the (UTC, host) clock pair to store; ``None``: now's (give one for
            data whose host clock is not this machine's, e.g. an imported recording).
        :returns: the records written per stream.
        :raises OSError: the file cannot be written.
        """
        pair = clock_pair if clock_pair is not None else (time.time_ns(), time.monotonic_ns())
        _append(self._wall, np.array([pair], dtype=np.int64))
        self._file.flush()
        self.flushed_counts = dict(self.counts)
        return self.flushed_counts

    def _release_reserve(self) -> None:
        """Free the reserved space and the writer lock (the file is closed or given up)."""
        if self._reserve is not None:
            os.close(self._reserve)
            self._reserve = None
        self._lock.release()

    def abort(self) -> bool:
        """Close after a write failure (full disk, I/O error): release the reserved space so
        HDF5 can write out its caches, then close. Returns whether the file closed; if not, it
        is left open for good, since closing a file HDF5 failed to write can crash the
        process (what the last flush wrote stays readable)."""
        self._release_reserve()
        try:
            if self._file.id.valid:
                self._file.flush()
                self._file.close()
            return True
        except (OSError, RuntimeError):
            ctypes.pythonapi.Py_IncRef(ctypes.py_object(self))  # never deallocated, never closed
            return False

    def close(self, clock_pair: tuple[int, int] | None = None) -> None:
        """Flush (see :meth:`flush`) and close the file (idempotent)."""
        if self._file.id.valid:
            self.flush(clock_pair)
            self._file.close()
        self._release_reserve()


def finalize_session(
    path: str | Path,
    attrs: dict[str, Any],
    truth: dict[str, np.ndarray] | None = None,
    log_lines: LogLines | None = None,
) -> None:
    """After a clean close: store clock fits per stream, end attributes, optional truth and
    the lines ``log_lines`` collected meanwhile (the clock fits' among them).

    The file is reopened without HDF5's file lock (``locking=False``): a reader that has the
    session open holds a shared lock that would otherwise make this fail."""
    with WriterLock(path):
        try:
            f = h5py.File(path, "r+", locking=False)
        except OSError as exc:
            raise SessionError(f"cannot reopen {path} to finish the session: {exc}") from None
        with f:
            finish_file(f, attrs, truth)
            if log_lines is not None and LOG in f:
                lines = log_lines.take()
                if log_lines.skipped:
                    lines.append(f"... {log_lines.skipped} further log lines not kept")
                _append(f[LOG], np.array(lines, dtype=object))


def finish_file(f: h5py.File, attrs: dict[str, Any], truth: dict[str, np.ndarray] | None) -> None:
    """Clock fits of every stream, optional truth and the end attributes, in an open file."""
    clock = f.require_group("clock")
    for spec in session_streams(f):
        n = consistent_rows(f[spec.name])
        t_dev, t_host = f[spec.name]["t_device_ns"][:n], f[spec.name]["t_host_ns"][:n]
        fit = fit_clock(t_dev, t_host)
        clock.require_group(spec.name).attrs.update(fit.to_attrs())
        log.info(
            "%s clock fit: %d pairs, drift %.2f ppm, jitter %.3f ms, latency %.3f ms",
            spec.name,
            fit.n_pairs,
            fit.drift_ppm,
            fit.jitter_ns / 1e6,
            fit.latency_ns / 1e6,
        )
    if truth:
        group = f.require_group("truth")
        for name, values in truth.items():
            if name in group:
                del group[name]
            group.create_dataset(name, data=np.asarray(values), fletcher32=True)
    f.attrs.update(
        {
            "end_utc_ns": time.time_ns(),
            "end_host_ns": time.monotonic_ns(),
            "complete": True,
            **attrs,
        }
    )
