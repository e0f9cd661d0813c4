"""Reading sessions: the only way other packages see the HDF5 layout.

Readers open sessions without HDF5's file lock (``locking=False``) and, while the recorder still
writes, in SWMR mode: they never modify the file, so they can neither block the recorder nor be
blocked by it.
"""

from __future__ import annotations

import json
import os
import socket
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import h5py
import numpy as np

from vbfe.acquire.resample import resample_at
from vbfe.acquire.session.clock import ClockFit, fit_clock
from vbfe.acquire.session.estimates import GROUP as ESTIMATES
from vbfe.acquire.session.estimates import EstimateStream, read_estimates
from vbfe.acquire.session.extra_streams import MARKS, RecordedStream
from vbfe.acquire.session.h5attrs import plain_attrs, text
from vbfe.acquire.session.layout import (
    CAMERA,
    FORCE,
    GAP_COLUMNS,
    GAP_REASONS,
    LOG,
    PROJECTOR,
    SCHEMA_VERSION,
    STREAMS,
    TIME_COLUMNS,
    StreamSpec,
    session_streams,
)
from vbfe.common.closing import ClosedOnExit
from vbfe.common.errors import SessionError
from vbfe.common.files import SESSION_FORMAT, is_hdf5
from vbfe.drivers.samples import ProjectorEvent, StereoFrame

FRAME_CORRECTION_ATTR = "frame_time_correction_ns"  # in /analysis, subtracted from frame times
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_GROWING_FLUSHES = 3  # a session flushed within this many flush intervals is still recorded


def _declared_size(path: Path) -> int | None:
    """End-of-file address the HDF5 superblock declares (None when there is no superblock)."""
    with open(path, "rb") as fh:
        offset = 0
        while True:
            fh.seek(offset)
            head = fh.read(64)
            if len(head) < 16:
                return None
            if head[:8] == _HDF5_SIGNATURE:
                break
            offset = 512 if offset == 0 else offset * 2
    version, size = head[8], head[13] if head[8] < 2 else head[9]
    start = {0: 24, 1: 28}.get(version, 12)
    if size != 8 or len(head) < start + 24:
        return None
    base, _, eof = struct.unpack_from("<QQQ", head, start)
    return offset + base + eof if base == 0 else base + eof


def _writer_alive(attrs: dict[str, Any]) -> bool:
    """Whether the process that wrote a session may still run (always True on another host)."""
    if str(attrs.get("writer_host", "")) != socket.gethostname():
        return True
    try:
        os.kill(int(attrs.get("writer_pid", 0)), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        pass
    return True


def consistent_rows(group: h5py.Group) -> int:
    """Rows of a stream group whose data and timestamps were all written: the shortest of its
    datasets, cut before the first row without a host time after one with it (a write cut
    short by a full disk can leave rows that exist but were never filled: zeros)."""
    lengths = [group[k].shape[0] for k in TIME_COLUMNS]
    n = min(lengths)
    is_set = group["t_host_ns"][:n] > 0
    first = int(np.argmax(is_set)) if is_set.any() else n
    unset = np.flatnonzero(~is_set[first:])
    return first + int(unset[0]) if len(unset) else n


OPEN_ATTEMPTS = 5  # a recorder finalizing the file changes its metadata for a moment
OPEN_RETRY_S = 0.2


def _open_retrying(path: Path, mode: str) -> h5py.File:
    """``h5py.File(path, mode)`` without HDF5's file lock, tried again for about a second while
    it fails for another reason than a write flag (a writer finalizing the file meanwhile)."""
    for _ in range(OPEN_ATTEMPTS - 1 if is_hdf5(path) else 0):
        try:
            return h5py.File(path, mode, locking=False)
        except OSError as exc:
            if "already open for write" in str(exc) or "open for read-only" in str(exc):
                raise
        time.sleep(OPEN_RETRY_S)
    return h5py.File(path, mode, locking=False)


def open_session_file(path: str | Path, mode: str = "r") -> tuple[h5py.File, bool]:
    """Open a session's HDF5 file; returns ``(file, closed_cleanly)``.

    A file whose recorder died (or still records) keeps its SWMR write flag; it is opened
    read-only in SWMR mode (everything up to the last flush is there). A file shorter than its
    superblock declares is refused at once (HDF5 would retry its reads for minutes). Anything
    else that fails is a SessionError.
    """
    path = Path(path)
    if not path.is_file():
        raise SessionError(f"session file {path} does not exist")
    declared, actual = _declared_size(path), path.stat().st_size
    if declared is not None and actual < declared:
        raise SessionError(
            f"{path} is truncated: {actual} bytes of the {declared} its header "
            "declares (copied or written only in part); nothing can be read"
        )
    try:
        return _open_retrying(path, mode), True
    except OSError as exc:
        if "already open for write" not in str(exc) and "open for read-only" not in str(exc):
            raise SessionError(
                f"{path} is not a readable HDF5 file (truncated or corrupt?): {exc}"
            ) from None
    if mode != "r":
        raise SessionError(
            f"{path} was not closed cleanly (the recorder stopped mid-recording); "
            "it can be read but not changed: copy it into a clean file with "
            "`vbfe inspect --recover OUT.h5`"
        )
    try:
        return h5py.File(path, "r", swmr=True, locking=False), False
    except OSError as exc:
        raise SessionError(f"{path} was not closed cleanly and cannot be read: {exc}") from None


def read_failure_reason(exc: BaseException) -> str:
    """HDF5's reason for a failed read, without the library's call-stack noise."""
    text = str(exc)
    if "Fletcher32" in text or "checksum" in text:
        return "checksum mismatch: the stored bytes changed after writing"
    if "metadata checksum" in text:
        return "metadata checksum mismatch: the file's structure changed after writing"
    if "filter returned failure" in text:
        return "checksum or decompression failed: the stored bytes changed after writing"
    return text


def check_session(f: h5py.File, path: Path) -> None:
    """Refuse a file that is not a vbfe session or is of a newer schema (closing it)."""
    if f.attrs.get("format") != SESSION_FORMAT:
        f.close()
        raise SessionError(
            f"{path} is an HDF5 file but not a vbfe session "
            f"(no format={SESSION_FORMAT!r} attribute)"
        )
    version = int(f.attrs.get("schema_version", -1))
    if version > SCHEMA_VERSION:
        f.close()
        raise SessionError(
            f"{path} has session schema {version}, newer than this vbfe "
            f"understands ({SCHEMA_VERSION}); update vbfe"
        )


# layout kind -> dtype kinds read
_KINDS = {"i": "iu", "f": "f", "u": "u", "b": "b", "S": "S", "T": "OST"}


def _check_layout(f: h5py.File, path: Path) -> tuple[str, tuple[StreamSpec, ...]]:
    """Check the datasets and attributes a reader needs, as the layout table says; returns the
    image encoding and the file's streams."""
    damaged = "the session file is damaged; record it again or restore a copy"
    camera = f.get(CAMERA)
    if not isinstance(camera, h5py.Group):
        raise SessionError(f"{path} has no 'camera' group: {damaged}")
    for attr in ("width", "height"):
        value = camera.attrs.get(attr)
        if not isinstance(value, (int, np.integer)) or value <= 0:
            raise SessionError(
                f"{path}: camera attribute {attr!r} is missing or not a positive "
                f"integer ({value!r}): {damaged}"
            )
    encoding = str(camera.attrs.get("encoding", "raw"))
    if encoding not in ("raw", "jpeg"):
        raise SessionError(f"{path}: unknown camera encoding {encoding!r}: {damaged}")
    try:
        streams = session_streams(f)
    except (ValueError, KeyError, TypeError) as exc:
        raise SessionError(
            f"{path}: the declared extra streams cannot be read ({exc}): {damaged}"
        ) from None
    datasets = [d for spec in streams for d in spec.datasets()]
    datasets += [("gaps", 2, "i"), ("clock_pairs", 2, "i")]
    for name, ndim, kind in datasets:
        ds = f.get(name)
        if not isinstance(ds, h5py.Dataset):
            raise SessionError(f"{path} has no dataset {name!r}: {damaged}")
        if ds.ndim != ndim or ds.dtype.kind not in _KINDS[kind]:
            raise SessionError(
                f"{path}: dataset {name!r} is {ds.dtype} {ds.shape}, not the "
                f"session layout's: {damaged}"
            )
    for spec in streams:
        for column in spec.columns:
            stored = f[f"{spec.name}/{column.name}"].shape[1:]
            if stored != column.shape:
                what = "images" if column.image else "columns"
                raise SessionError(
                    f"{path}: {spec.name}/{column.name} holds {stored} {what}, "
                    f"the session says {column.shape}: {damaged}"
                )
    if f["gaps"].shape[1] != len(GAP_COLUMNS) or f["clock_pairs"].shape[1] != 2:
        raise SessionError(
            f"{path}: gaps or clock_pairs has the wrong number of columns: {damaged}"
        )
    return encoding, streams


class SessionReader(ClosedOnExit):
    """Read-only access to a recorded session (frames, forces, events, clock fits, metadata).

    Use it as a context manager (``with SessionReader(path) as reader:``) or call
    :meth:`close`. A session still being written (SWMR) or cut short by a crash is read up to
    its last complete records (``complete`` and ``closed_cleanly`` say which).

    :param path: the session file (HDF5, written by :class:`SessionWriter`).
    :raises SessionError: the file is missing, not a vbfe session, of an unknown schema
        version, or too damaged to read (the message names the file).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file, self.closed_cleanly = open_session_file(self.path)
        try:
            self._open()
        except (OSError, KeyError, ValueError, TypeError) as exc:
            self._file.close()
            raise SessionError(
                f"{self.path} cannot be read (corrupt or truncated?): "
                f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
            ) from None
        except SessionError:
            self._file.close()
            raise

    def _open(self) -> None:
        check_session(self._file, self.path)
        f = self._file
        self.complete = bool(f.attrs.get("complete", False)) and self.closed_cleanly
        self.encoding, streams = _check_layout(f, self.path)
        self.streams = {spec.name: spec for spec in streams}
        self.metadata  # noqa: B018 - fails here, naming the file, when the JSON is damaged
        cam = f[CAMERA]
        self._lengths = {
            spec.name: min(
                [consistent_rows(f[spec.name])]
                + [f[spec.name][c.name].shape[0] for c in spec.columns]
            )
            for spec in streams
        }
        self._fits: dict[str, ClockFit] = {}
        self._times: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._image_data = {
            eye: cam[f"{eye}_jpeg" if self.encoding == "jpeg" else eye] for eye in ("left", "right")
        }
        self._jpeg_index = (
            {eye: cam[f"{eye}_jpeg_index"][: self.n_frames] for eye in ("left", "right")}
            if self.encoding == "jpeg"
            else {}
        )

    @property
    def growing(self) -> bool:
        """True while a recorder is still writing the session: it flushed within the last few
        flush intervals and, on this machine, its process is alive. False for finished and
        for interrupted sessions."""
        if self.closed_cleanly or not _writer_alive(dict(self._file.attrs)):
            return False
        pairs = self._file["clock_pairs"]
        pairs.refresh()
        if pairs.shape[0] == 0:
            last_utc_ns = int(self._file.attrs.get("start_utc_ns", 0))
        else:
            last_utc_ns = int(pairs[pairs.shape[0] - 1, 0])
        interval_s = float(self._file.attrs.get("flush_interval_s", 1.0))
        return time.time_ns() - last_utc_ns < _GROWING_FLUSHES * max(interval_s, 1.0) * 1e9

    # -- container protocol -------------------------------------------------------------
    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def _read(self, name: str, n: int | None = None) -> np.ndarray:
        try:
            ds = self._file[name]
            return ds[:n] if n is not None else ds[()]
        except (OSError, KeyError, ValueError) as exc:
            raise SessionError(
                f"cannot read {name} from {self.path} (damaged?): {read_failure_reason(exc)}"
            ) from None

    # -- frames -------------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        """Number of complete stereo frames."""
        return self._lengths[CAMERA]

    @property
    def frame_size(self) -> tuple[int, int]:
        """``(width, height)`` of one eye."""
        cam = self._file[CAMERA]
        return int(cam.attrs["width"]), int(cam.attrs["height"])

    def _image(self, eye: str, i: int) -> np.ndarray:
        data = self._image_data[eye]
        try:
            if self.encoding == "jpeg":
                offset, length = self._jpeg_index[eye][i]
                image = cv2.imdecode(data[offset : offset + length], cv2.IMREAD_COLOR)
                if image is None:
                    raise OSError("JPEG data does not decode")
                return image
            return data[i]
        except OSError as exc:
            raise SessionError(
                f"frame {i} of {self.path} is damaged: dataset "
                f"{data.name} cannot be read ({read_failure_reason(exc)})"
            ) from None

    def encoded_frame(self, i: int) -> tuple[bytes, bytes] | None:
        """The stored JPEG bytes (left, right) of frame ``i`` of an ``mjpeg`` session (the
        camera's own when it sent them), or None for raw sessions."""
        if self.encoding != "jpeg":
            return None
        blobs = []
        for eye in ("left", "right"):
            offset, length = self._jpeg_index[eye][i]
            try:
                blobs.append(self._image_data[eye][offset : offset + length].tobytes())
            except OSError as exc:
                raise SessionError(
                    f"frame {i} of {self.path} is damaged: {read_failure_reason(exc)}"
                ) from None
        return blobs[0], blobs[1]

    def frame(self, i: int) -> StereoFrame:
        """One stereo frame with its recorded device and host timestamps (not clock-corrected).

        :param i: the frame's index (negative counts from the end).
        :returns: the frame, its images decoded (BGR).
        :raises IndexError: ``i`` is out of range.
        """
        if not -self.n_frames <= i < self.n_frames:
            raise IndexError(f"frame {i} out of range: {self.path} has {self.n_frames} frames")
        i %= self.n_frames
        t_dev, t_host, seq = self.stream_times(CAMERA)
        return StereoFrame(
            left=self._image("left", i),
            right=self._image("right", i),
            seq=int(seq[i]),
            t_device_ns=int(t_dev[i]),
            t_host_ns=int(t_host[i]),
        )

    def iter_frames(self, start: int = 0, stop: int | None = None) -> Iterator[StereoFrame]:
        """Frames ``start`` … ``stop - 1`` in order."""
        stop = self.n_frames if stop is None else min(stop, self.n_frames)
        for i in range(start, stop):
            yield self.frame(i)

    # -- raw streams ----------------------------------------------------------------------
    def stream_times(self, stream: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Recorded ``(t_device_ns, t_host_ns, seq)`` of one stream (camera, force, projector
        or an extra stream)."""
        if stream not in self._times:
            n = self.stream_length(stream)
            t_device, t_host, seq = (self._read(f"{stream}/{k}", n) for k in TIME_COLUMNS)
            self._times[stream] = (t_device, t_host, seq)
        return self._times[stream]

    def stream_length(self, stream: str) -> int:
        """Complete records of ``stream``."""
        if stream not in self._lengths:
            raise SessionError(
                f"{self.path} has no stream {stream!r} (streams: {list(self.streams)})"
            )
        return self._lengths[stream]

    def stream_column(self, stream: str, column: str) -> np.ndarray:
        """One data column of a stream (e.g. an extra stream's ``values``), complete rows."""
        spec = self.streams.get(stream)
        if spec is None or column not in [c.name for c in spec.columns]:
            raise SessionError(f"{self.path} has no column {column!r} in stream {stream!r}")
        values = self._read(f"{stream}/{column}", self.stream_length(stream))
        if values.dtype.kind == "O":  # text
            return np.array([text(v) for v in values], dtype=object)
        return values

    def clock_fit(self, stream: str) -> ClockFit:
        """The device-to-host clock fit of a stream (stored at close, recomputed otherwise)."""
        if stream not in self._fits:
            stored = self._file.get(f"clock/{stream}")
            try:  # a stored fit with attributes missing or damaged is recomputed
                self._fits[stream] = ClockFit.from_attrs(dict(stored.attrs))
            except (AttributeError, KeyError, TypeError, ValueError):
                t_dev, t_host, _ = self.stream_times(stream)
                self._fits[stream] = fit_clock(t_dev, t_host)
        return self._fits[stream]

    # -- synchronized times and force -----------------------------------------------------
    def frame_times_ns(self) -> np.ndarray:
        """Per-frame capture time on the host clock (clock fit, minus any stored correction)."""
        t_dev = self.stream_times(CAMERA)[0]
        correction = int(self.analysis().get(FRAME_CORRECTION_ATTR, 0))
        return self.clock_fit(CAMERA).to_host(t_dev) - correction

    def force_times_ns(self) -> np.ndarray:
        """Per-sample force time on the host clock (after the clock fit)."""
        return self.clock_fit(FORCE).to_host(self.stream_times(FORCE)[0])

    def forces_n(self) -> np.ndarray:
        """All force samples, ``(n, 3)`` newtons."""
        return self._read("force/force_n", self._lengths[FORCE])

    @property
    def force_axes(self) -> list[str]:
        """Names of the force columns."""
        return [str(a) for a in self._file["force/force_n"].attrs.get("axes", ["x", "y", "z"])]

    def force_at_frames(self, max_gap_s: float = 0.05) -> np.ndarray:
        """The force interpolated at each frame's synchronized time.

        :param max_gap_s: frames inside a force gap longer than this get NaN rather than an
            invented value (as do frames outside the force record).
        :returns: ``(n_frames, 3)`` newtons.
        """
        return resample_at(
            self.frame_times_ns(), self.force_times_ns(), self.forces_n(), max_gap_s * 1e9
        )

    # -- extra streams (``[streams]``) and event marks ----------------------------------------
    def stream_names(self) -> list[str]:
        """Names of the extra streams recorded with the session (e.g. ``[streams]`` keys)."""
        return [name for name in self.streams if name not in (*STREAMS, MARKS, ESTIMATES)]

    def stream(self, name: str) -> RecordedStream:
        """An extra stream: values or marker text, host and publisher times, channel names and
        units, the time corrections measured while recording.

        :param name: the stream's name (e.g. ``"robot"``, a ``[streams]`` key).
        :raises SessionError: the session has no such stream.
        """
        if name not in self.stream_names():
            raise SessionError(
                f"{self.path} has no stream {name!r}; it has "
                f"{', '.join(self.stream_names()) or 'no extra streams'}"
            )
        column = self.streams[name].columns[0].name
        attrs = plain_attrs(self._file[f"{name}/{column}"].attrs)
        data = self.stream_column(name, column)
        t_device, t_host, seq = self.stream_times(name)
        try:
            at_end = json.loads(self.attrs.get("devices_at_end_json", "{}")).get(name, {})
        except (json.JSONDecodeError, AttributeError):
            at_end = {}
        channels = [str(c) for c in attrs.pop("channels", [column])]
        return RecordedStream(
            name=name,
            channels=channels,
            units=[str(u) for u in attrs.pop("channel_units", [attrs.get("units", "")])],
            t_host_ns=t_host,
            t_device_ns=t_device,
            seq=seq,
            values=None if column == "text" else data.reshape(len(seq), -1),
            text=data if column == "text" else None,
            corrections=np.array(at_end.get("time_corrections", []), np.int64).reshape(-1, 2),
            attrs=attrs,
        )

    def at_frames(self, name: str, max_gap_s: float | None = None) -> np.ndarray:
        """A numeric extra stream at each frame's synchronized time: ``(n_frames, channels)``,
        interpolated; NaN outside the stream or inside a gap longer than ``max_gap_s`` (default:
        five sample periods of its nominal rate, else 50 ms)."""
        stream = self.stream(name)
        if stream.values is None:
            raise SessionError(
                f"stream {name} of {self.path} holds event markers, not values; "
                "read them with events()"
            )
        if max_gap_s is None:
            rate = float(stream.attrs.get("nominal_rate_hz", 0.0))
            max_gap_s = 5 / rate if rate > 0 else 0.05
        return resample_at(self.frame_times_ns(), stream.t_host_ns, stream.values, max_gap_s * 1e9)

    def events(self) -> list[dict[str, Any]]:
        """Every event mark by host time: ``{"t_host_ns", "source", "text"}`` (source
        ``"mark"`` for ``vbfe mark``, else the marker stream's name)."""
        events = []
        marker_streams = [
            n
            for n, spec in self.streams.items()
            if n not in STREAMS and [c.name for c in spec.columns] == ["text"]
        ]
        for name in marker_streams:
            t_host = self.stream_times(name)[1]
            events += [
                {
                    "t_host_ns": int(t),
                    "source": "mark" if name == MARKS else name,
                    "text": str(text),
                }
                for t, text in zip(t_host, self.stream_column(name, "text"), strict=False)
            ]
        return sorted(events, key=lambda e: e["t_host_ns"])

    # -- events, gaps, metadata ---------------------------------------------------------
    def projector_events(self) -> list[ProjectorEvent]:
        """Projector events in recording order."""
        n = self._lengths[PROJECTOR]
        t_dev, t_host, seq = self.stream_times(PROJECTOR)
        names = self._read("projector/pattern", n)
        ids = self._read("projector/frame_id", n)
        return [
            ProjectorEvent(
                pattern=names[i].decode(),
                frame_id=int(ids[i]),
                seq=int(seq[i]),
                t_host_ns=int(t_host[i]),
                t_device_ns=int(t_dev[i]),
            )
            for i in range(n)
        ]

    def gaps(self) -> list[dict[str, Any]]:
        """Gaps the recorder marked (queue overflow, device disconnected), as dicts."""
        rows = self._read("gaps")
        streams = [text(v) for v in self._file["gaps"].attrs.get("streams", STREAMS)]
        out = []
        for row in rows:
            gap: dict[str, Any] = dict(zip(GAP_COLUMNS, (int(v) for v in row), strict=False))
            gap["stream"] = streams[gap["stream"]]
            gap["reason"] = GAP_REASONS[gap["reason"]]
            out.append(gap)
        return out

    def log(self) -> list[str]:
        """The recording's log lines (empty for sessions written before they were kept)."""
        if LOG not in self._file:
            return []
        return [text(v) for v in self._file[LOG][:]]

    def clock_pairs(self) -> np.ndarray:
        """``(n, 2)`` pairs of (UTC ns, host monotonic ns) taken at every flush."""
        return self._read("clock_pairs")

    @property
    def attrs(self) -> dict[str, Any]:
        """The root attributes (schema and software version, start time, drop counters …)."""
        try:
            return plain_attrs(self._file.attrs)
        except OSError as exc:
            raise SessionError(
                f"cannot read the attributes of {self.path} (corrupt?): {exc}"
            ) from None

    @property
    def metadata(self) -> dict[str, Any]:
        """Operator, notes, devices, conditions, bench, … as given when recording started."""
        attrs = self.attrs
        try:
            meta = json.loads(attrs.get("metadata_json", "{}"))
        except (json.JSONDecodeError, TypeError):
            raise SessionError(
                f"{self.path}: the metadata_json attribute is not JSON (damaged "
                "file); record it again or restore a copy"
            ) from None
        if not isinstance(meta, dict):
            raise SessionError(f"{self.path}: the metadata_json attribute is not a JSON object")
        for key in (
            "operator",
            "notes",
            "schema_version",
            "software_version",
            "compression",
            "start_utc_ns",
        ):
            meta.setdefault(key, attrs.get(key))
        return meta

    def calibration_yaml(self) -> str | None:
        """The calibration stored with the session (OpenCV YAML text), if any."""
        if "calibration_yaml" not in self._file:
            return None
        return text(self._read("calibration_yaml"))

    def truth(self, name: str) -> np.ndarray | None:
        """A ground-truth array of a simulated session (e.g. per-frame true force), or None."""
        key = f"truth/{name}"
        return self._read(key) if key in self._file else None

    def truth_names(self) -> list[str]:
        """Names of the stored ground-truth arrays."""
        return sorted(self._file["truth"]) if "truth" in self._file else []

    def estimates(self) -> EstimateStream | None:
        """The live force estimates stored with the session (schema 2) of its recorded
        frames, or ``None``."""
        group = self._file.get(ESTIMATES)
        rows = consistent_rows(group) if group is not None and "t_host_ns" in group else 0
        seqs = self.stream_times(CAMERA)[2][: self.n_frames]
        return read_estimates(self._file, self.path, seqs, rows)

    def analysis(self) -> dict[str, Any]:
        """Results stored by analyses such as verify-sync (``/analysis`` attributes)."""
        group = self._file.get("analysis")
        if group is None:
            return {}
        return plain_attrs(group.attrs)
