"""Low-level session writer: creates the HDF5 layout, appends samples, flushes in SWMR mode.

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

import vbfe
from vbfe.acquire.session.clock import fit_clock
from vbfe.acquire.errors import SessionError
from vbfe.acquire.session.reader import SessionReader
from vbfe.acquire.session.layout import (COMPRESSIONS, FORMAT_NAME, GAP_COLUMNS, GAP_REASONS,
                                 JPEG_QUALITY, PATTERN_NAME_DTYPE, SCHEMA_VERSION, STREAMS,
                                 image_filter)
from vbfe.acquire.session.extra_streams import ExtraStreams
from vbfe.acquire.session.extra_streams import keep_consistent_rows as keep_extra_rows
from vbfe.acquire.session.h5series import TIME_CHUNK, append, series
from vbfe.acquire.session.reader import consistent_rows, open_session_file
from vbfe.drivers.samples import ForceSample, ProjectorEvent, StereoFrame
from vbfe.drivers.streams.chunk import StreamChunk, StreamInfo

_JPEG_CHUNK = 1 << 20
_RESERVE_BYTES = 16 << 20  # held back so HDF5 can still write out its caches after a full disk


def _reserve_space(directory: Path) -> int | None:
    """Hold free space in an unlinked file (the kernel frees it when the descriptor closes,
    also on SIGKILL); returns the descriptor, or None where nothing could be reserved."""
    try:
        fd, name = tempfile.mkstemp(dir=directory, prefix=".vbfe-reserve-")
    except OSError:
        return None
    os.unlink(name)
    with contextlib.suppress(OSError):
        os.posix_fallocate(fd, 0, min(_RESERVE_BYTES, shutil.disk_usage(directory).free // 8))
    return fd


def _encode_jpeg(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise SessionError("OpenCV could not JPEG-encode a frame for the mjpeg compression")
    return buf.tobytes()


class SessionWriter:
    """Writes one session file; call the ``append_*`` methods from a single thread."""

    def __init__(self, path: str | Path, frame_size: tuple[int, int], compression: str = "lzf",
                 metadata: dict[str, Any] | None = None, calibration_yaml: str | None = None,
                 force_axes: Sequence[str] = ("x", "y", "z"), flush_interval_s: float = 1.0,
                 extra_streams: Sequence[StreamInfo] = ()) -> None:
        if compression not in COMPRESSIONS:
            raise SessionError(f"unknown compression {compression!r} for {path}; choose one of "
                               f"{COMPRESSIONS}")
        self.path = Path(path)
        self.compression = compression
        self.bytes_written = 0  # uncompressed payload bytes
        width, height = frame_size
        metadata = dict(metadata or {})
        self._reserve = _reserve_space(self.path.parent)
        try:
            self._file = h5py.File(self.path, "w", libver="latest")
        except OSError as exc:
            self._release_reserve()
            raise SessionError(f"cannot create session file {self.path}: {exc}") from None
        f = self._file
        f.attrs.update({
            "format": FORMAT_NAME, "schema_version": SCHEMA_VERSION,
            "software_version": vbfe.__version__, "compression": compression,
            "operator": str(metadata.get("operator", "")), "notes": str(metadata.get("notes", "")),
            "start_utc_ns": time.time_ns(), "start_host_ns": time.monotonic_ns(),
            "metadata_json": json.dumps(metadata, default=str), "complete": False,
            "flush_interval_s": float(flush_interval_s),
            "writer_host": socket.gethostname(), "writer_pid": os.getpid(),
        })
        cam = f.create_group("camera")
        cam.attrs.update({"width": width, "height": height, "encoding":
                          "jpeg" if compression == "mjpeg" else "raw", "color": "BGR"})
        self._images: dict[str, h5py.Dataset] = {}
        self._jpeg: dict[str, tuple[h5py.Dataset, h5py.Dataset]] = {}
        for eye in ("left", "right"):
            if compression == "mjpeg":
                self._jpeg[eye] = (series(cam, f"{eye}_jpeg", np.uint8, chunk=_JPEG_CHUNK),
                                   series(cam, f"{eye}_jpeg_index", np.int64, width=2, chunk=256))
            else:
                self._images[eye] = cam.create_dataset(
                    eye, shape=(0, height, width, 3), maxshape=(None, height, width, 3),
                    chunks=(1, height, width, 3), dtype=np.uint8, fletcher32=True,
                    # no chunk cache: a frame is compressed and written as it is appended, so a
                    # flush has only metadata and the small time series left to write
                    rdcc_nbytes=0, rdcc_w0=1.0, **image_filter(compression))
        force = f.create_group("force")
        self._force_n = series(force, "force_n", np.float64, width=len(force_axes))
        self._force_n.attrs.update({"units": "N", "axes": list(force_axes)})
        proj = f.create_group("projector")
        self._pattern = series(proj, "pattern", PATTERN_NAME_DTYPE, chunk=64)
        self._frame_id = series(proj, "frame_id", np.int64, chunk=64)
        self._times = {}
        for name, group, chunk in (("camera", cam, 256), ("force", force, TIME_CHUNK),
                                   ("projector", proj, 64)):
            self._times[name] = tuple(series(group, key, np.int64, chunk=chunk)
                                      for key in ("t_device_ns", "t_host_ns", "seq"))
            for key in ("t_device_ns", "t_host_ns"):
                group[key].attrs["units"] = "ns"
        self._gaps = series(f, "gaps", np.int64, width=len(GAP_COLUMNS), chunk=64)
        self._gap_streams = [*STREAMS, *(info.name for info in extra_streams)]
        self._gaps.attrs.update({"columns": list(GAP_COLUMNS), "streams": self._gap_streams,
                                 "reasons": list(GAP_REASONS)})
        self.extra = ExtraStreams(f, extra_streams)
        self._wall = series(f, "clock_pairs", np.int64, width=2, chunk=64)
        self._wall.attrs["columns"] = ["t_utc_ns", "t_host_ns"]
        if calibration_yaml is not None:
            f.create_dataset("calibration_yaml", data=calibration_yaml,
                             dtype=h5py.string_dtype())
        f.swmr_mode = True
        self.counts = {name: 0 for name in STREAMS}
        self.flushed_counts = {**self.counts, **self.extra.counts}

    def _append_times(self, stream: str, samples: Sequence[Any]) -> None:
        t_dev, t_host, seq = self._times[stream]
        append(t_dev, np.array([s.t_device_ns for s in samples], dtype=np.int64))
        append(t_host, np.array([s.t_host_ns for s in samples], dtype=np.int64))
        append(seq, np.array([s.seq for s in samples], dtype=np.int64))
        self.counts[stream] += len(samples)

    def append_frames(self, frames: Sequence[StereoFrame]) -> None:
        """Append stereo frames (image data first, timestamps last, so a reader never sees a
        timestamp whose image is missing)."""
        if not frames:
            return
        if self.compression == "mjpeg":
            for i, eye in enumerate(("left", "right")):
                blobs = [fr.encoded[i] if fr.encoded is not None
                         else _encode_jpeg(getattr(fr, eye)) for fr in frames]
                data, index = self._jpeg[eye]
                start = data.shape[0]
                lengths = np.array([len(b) for b in blobs], dtype=np.int64)
                offsets = start + np.concatenate([[0], np.cumsum(lengths)[:-1]])
                append(data, np.frombuffer(b"".join(blobs), dtype=np.uint8))
                append(index, np.stack([offsets, lengths], axis=1))
                self.bytes_written += int(lengths.sum())
        else:
            expected = self._images["left"].shape[1:]
            for fr in frames:
                if fr.left.shape != expected or fr.right.shape != expected:
                    raise SessionError(f"frame {fr.seq} for {self.path} is {fr.left.shape}, "
                                       f"expected {expected} (did the camera change size?)")
            for eye, ds in self._images.items():
                n = ds.shape[0]
                ds.resize(n + len(frames), axis=0)
                for k, fr in enumerate(frames):
                    ds[n + k] = getattr(fr, eye)
                self.bytes_written += len(frames) * fr.left.nbytes
        self._append_times("camera", frames)

    def append_forces(self, samples: Sequence[ForceSample]) -> None:
        """Append a batch of force samples."""
        if not samples:
            return
        append(self._force_n, np.array([s.force_n for s in samples], dtype=np.float64))
        self.bytes_written += len(samples) * (self._force_n.shape[1] * 8 + 24)
        self._append_times("force", samples)

    def append_events(self, events: Sequence[ProjectorEvent]) -> None:
        """Append projector events (pattern shown, frame ID)."""
        if not events:
            return
        append(self._pattern, np.array([e.pattern.encode()[:64] for e in events],
                                        dtype=PATTERN_NAME_DTYPE))
        append(self._frame_id, np.array([e.frame_id for e in events], dtype=np.int64))
        self._append_times("projector", events)

    def append_chunks(self, chunks: Sequence[StreamChunk]) -> None:
        """Append chunks of the extra streams."""
        self.bytes_written += self.extra.append(chunks)

    def add_mark(self, text: str, t_host_ns: int) -> None:
        """Add an event mark (``vbfe mark``) at host time ``t_host_ns``."""
        self.extra.mark(text, t_host_ns)

    def add_gap(self, stream: str, reason: str, last_seq: int, next_seq: int, t_host_ns: int,
                count: int) -> None:
        """Mark a gap in a stream: samples lost between ``last_seq`` and ``next_seq``."""
        append(self._gaps, np.array([[self._gap_streams.index(stream), GAP_REASONS.index(reason),
                                       last_seq, next_seq, t_host_ns, count]], dtype=np.int64))

    def flush(self) -> dict[str, int]:
        """Make everything appended so far durable and visible to readers; returns the counts."""
        append(self._wall, np.array([[time.time_ns(), time.monotonic_ns()]], dtype=np.int64))
        self._file.flush()
        self.flushed_counts = {**self.counts, **self.extra.counts}
        return self.flushed_counts

    def _release_reserve(self) -> None:
        if self._reserve is not None:
            os.close(self._reserve)
            self._reserve = None

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

    def close(self) -> None:
        """Flush and close the file (idempotent)."""
        if self._file.id.valid:
            self.flush()
            self._file.close()
        self._release_reserve()


def finalize_session(path: str | Path, attrs: dict[str, Any],
                     truth: dict[str, np.ndarray] | None = None) -> None:
    """After a clean close: store clock fits per stream, end attributes and optional truth.

    The file is reopened without HDF5's file lock (``locking=False``): a reader that has the
    session open holds a shared lock that would otherwise make this fail."""
    try:
        f = h5py.File(path, "r+", locking=False)
    except OSError as exc:
        raise SessionError(f"cannot reopen {path} to finish the session: {exc}") from None
    with f:
        _finish(f, attrs, truth)


def _finish(f: h5py.File, attrs: dict[str, Any], truth: dict[str, np.ndarray] | None) -> None:
    clock = f.require_group("clock")
    for stream in STREAMS:
        n = consistent_rows(f[stream])
        t_dev, t_host = f[stream]["t_device_ns"][:n], f[stream]["t_host_ns"][:n]
        clock.require_group(stream).attrs.update(fit_clock(t_dev[:n], t_host[:n]).to_attrs())
    if truth:
        group = f.require_group("truth")
        for name, values in truth.items():
            if name in group:
                del group[name]
            group.create_dataset(name, data=np.asarray(values), fletcher32=True)
    f.attrs.update({"end_utc_ns": time.time_ns(), "end_host_ns": time.monotonic_ns(),
                    "complete": True, **attrs})


def _trim(group: h5py.Group, keys: Sequence[str], n: int) -> int:
    """Cut the datasets ``keys`` of ``group`` to ``n`` rows; returns the rows removed."""
    removed = 0
    for key in keys:
        if key in group and group[key].shape[0] > n:
            removed = max(removed, group[key].shape[0] - n)
            group[key].resize(n, axis=0)
    return removed


def _keep_consistent_rows(f: h5py.File) -> dict[str, int]:
    """Cut every stream of a copied session to its rows with consistent timestamps (a writer
    that died mid-write can leave rows that exist but were never filled); returns the rows
    dropped per stream."""
    dropped = {}
    for stream in STREAMS:
        group = f[stream]
        n = consistent_rows(group)
        keys = ["t_device_ns", "t_host_ns", "seq"]
        keys += {"camera": ["left", "right", "left_jpeg_index", "right_jpeg_index"],
                 "force": ["force_n"], "projector": ["pattern", "frame_id"]}[stream]
        dropped[stream] = _trim(group, keys, n)
        for eye in ("left", "right"):
            if stream == "camera" and f"{eye}_jpeg_index" in group:
                index = group[f"{eye}_jpeg_index"]
                end = int(index[n - 1].sum()) if n else 0
                _trim(group, [f"{eye}_jpeg"], end)
    for name in ("gaps", "clock_pairs"):
        column = 4 if name == "gaps" else 1  # t_host_ns
        rows = f[name][:]
        valid = np.flatnonzero(rows[:, column] <= 0) if len(rows) else np.zeros(0, int)
        _trim(f, [name], int(valid[0]) if len(valid) else len(rows))
    return dropped


def recover_session(path: str | Path, out_path: str | Path,
                    overwrite: bool = False) -> tuple[Path, dict[str, int]]:
    """Copy a session whose recorder died (SWMR write flag still set) into a clean, finalized
    file ``out_path``: every row up to the last flush whose timestamps are consistent, plus
    clock fits. Returns the new file and the rows dropped per stream. The copy is written under
    a temporary name and renamed when complete."""
    out_path = Path(out_path)
    if out_path.exists() and not overwrite:
        raise SessionError(f"{out_path} already exists; choose a new file for the recovered copy")
    if not out_path.parent.is_dir():
        raise SessionError(f"cannot recover into {out_path}: folder {out_path.parent} does not "
                           "exist")
    with SessionReader(path):  # a damaged file fails here, naming what is wrong
        pass
    src, _ = open_session_file(path)
    tmp = out_path.with_name(f".{out_path.name}.partial")
    try:
        with src, h5py.File(tmp, "w", libver="latest") as dst:
            if src.attrs.get("format") != FORMAT_NAME:
                raise SessionError(f"{path} is not a vbfe session; nothing to recover")
            dst.attrs.update(dict(src.attrs))
            for name in src:
                src.copy(src[name], dst, name=name)
            dropped = {**_keep_consistent_rows(dst), **keep_extra_rows(dst)}
            _finish(dst, {"end_reason": "recovered: the recording was interrupted",
                          "recovered_from": str(Path(path).absolute()),
                          **{f"{s}_recovery_dropped": n for s, n in dropped.items()}}, None)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise SessionError(f"{path} cannot be recovered (damaged beyond its last flush?): "
                           f"{exc}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, out_path)
    return out_path, dropped
