"""Extra streams in a session (``/streams/<name>``, from ``[streams]``) and the session's own
event marks (``/events``, from ``vbfe mark``); both created with the layout, appended while
recording, read back by :class:`~vbfe.acquire.SessionReader`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import h5py
import numpy as np

from vbfe.acquire.session.h5attrs import plain_attrs
from vbfe.acquire.session.h5series import append, series
from vbfe.drivers.streams.chunk import StreamChunk, StreamInfo

GROUP = "streams"
EVENTS = "events"
TEXT_DTYPE = "S256"  # marker and mark text, UTF-8, cut at 256 bytes
SOURCE_DTYPE = "S64"
CORRECTION_COLUMNS = ("t_host_ns", "correction_ns")
MARK_SOURCE = "mark"  # the source of the session's own marks in the event list


@dataclass
class RecordedStream:
    """One extra stream as recorded: ``values`` ``(n, channels)`` float64 (numeric streams) or
    ``text`` ``(n, channels)`` str (marker streams); times on the host clock (``t_host_ns``)
    and the publisher's (``t_device_ns``); the time corrections ``(t_host_ns, correction_ns)``
    that mapped one to the other; the stream's description."""

    name: str
    channels: list[str]
    units: list[str]
    t_host_ns: np.ndarray
    t_device_ns: np.ndarray
    seq: np.ndarray
    values: np.ndarray | None
    text: np.ndarray | None
    corrections: np.ndarray
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def markers(self) -> bool:
        """Whether this is a marker (string) stream."""
        return self.text is not None

    def __len__(self) -> int:
        return len(self.t_host_ns)


def _text(values: np.ndarray) -> np.ndarray:
    return np.array([str(v).encode("utf-8")[:256] for v in values.ravel()],
                     dtype=TEXT_DTYPE).reshape(values.shape)


class ExtraStreams:
    """The writer's part: creates ``/streams/<name>`` per stream and ``/events`` (call before
    the file enters SWMR mode), then appends chunks and marks; ``counts`` per stream."""

    def __init__(self, f: h5py.File, infos: Sequence[StreamInfo]) -> None:
        self._datasets: dict[str, dict[str, h5py.Dataset]] = {}
        root = f.create_group(GROUP)
        for info in infos:
            group = root.create_group(info.name)
            group.attrs.update({"lsl_name": info.lsl_name, "type": info.type,
                                "source_id": info.source_id, "hostname": info.hostname,
                                "nominal_rate_hz": info.nominal_rate_hz, "markers": info.markers,
                                "channels": list(info.channels), "units": list(info.units),
                                "info_xml": info.info_xml})
            chunk = max(64, min(4096, int(info.nominal_rate_hz) or 64))
            data = (series(group, "text", TEXT_DTYPE, width=info.n_channels, chunk=64)
                    if info.markers else
                    series(group, "values", np.float64, width=info.n_channels, chunk=chunk))
            sets = {"data": data, "time_correction": series(group, "time_correction", np.int64,
                                                           width=2, chunk=64)}
            sets["time_correction"].attrs["columns"] = list(CORRECTION_COLUMNS)
            for key in ("t_device_ns", "t_host_ns", "seq"):
                sets[key] = series(group, key, np.int64, chunk=chunk)
            for key in ("t_device_ns", "t_host_ns"):
                sets[key].attrs["units"] = "ns"
            self._datasets[info.name] = sets
        events = f.create_group(EVENTS)
        self._events = {"t_host_ns": series(events, "t_host_ns", np.int64, chunk=64),
                        "source": series(events, "source", SOURCE_DTYPE, chunk=64),
                        "text": series(events, "text", TEXT_DTYPE, chunk=64)}
        self.counts = {name: 0 for name in self._datasets}

    def append(self, chunks: Sequence[StreamChunk]) -> int:
        """Append chunks (of any of the streams); returns the payload bytes written."""
        written = 0
        for chunk in chunks:
            sets = self._datasets[chunk.stream]
            if chunk.corrections:
                append(sets["time_correction"], np.array(chunk.corrections, np.int64))
            data = (_text(chunk.values) if sets["data"].dtype.kind == "S"
                    else np.asarray(chunk.values, np.float64))
            append(sets["data"], data)  # data first, times last (see consistent_rows)
            append(sets["t_device_ns"], chunk.sample_t_device_ns)
            append(sets["seq"], chunk.seq + np.arange(len(chunk), dtype=np.int64))
            append(sets["t_host_ns"], chunk.sample_t_host_ns)
            self.counts[chunk.stream] += len(chunk)
            written += data.nbytes + 24 * len(chunk)
        return written

    def mark(self, text: str, t_host_ns: int, source: str = MARK_SOURCE) -> None:
        """Add an event mark at host time ``t_host_ns``."""
        append(self._events["text"], _text(np.array([text])))
        append(self._events["source"], np.array([source.encode()[:64]], SOURCE_DTYPE))
        append(self._events["t_host_ns"], np.array([t_host_ns], np.int64))


def stream_names(f: h5py.File) -> list[str]:
    """Names of the extra streams a session holds (in recording order)."""
    return list(f[GROUP]) if GROUP in f else []


def _rows(group: h5py.Group, data_key: str) -> int:
    """Rows whose data and times were all written (the times are written last)."""
    return min(group[k].shape[0] for k in (data_key, "t_device_ns", "seq", "t_host_ns"))


def read_stream(f: h5py.File, name: str) -> RecordedStream:
    """One extra stream (KeyError when the session has none of that name)."""
    group = f[GROUP][name]
    attrs = plain_attrs(group.attrs)
    markers = "text" in group
    n = _rows(group, "text" if markers else "values")
    data = group["text" if markers else "values"][:n]
    return RecordedStream(
        name=name, channels=[str(c) for c in attrs.get("channels", [])],
        units=[str(u) for u in attrs.get("units", [])], t_host_ns=group["t_host_ns"][:n],
        t_device_ns=group["t_device_ns"][:n], seq=group["seq"][:n],
        values=None if markers else data,
        text=np.char.decode(data, "utf-8", "replace") if markers else None,
        corrections=group["time_correction"][()],
        attrs={k: v for k, v in attrs.items() if k not in ("channels", "units")})


def read_events(f: h5py.File) -> list[dict[str, Any]]:
    """Every event mark, from ``/events`` and the marker streams, by host time:
    ``{"t_host_ns", "source", "text"}`` (source ``mark`` or the marker stream's name)."""
    events = []
    if EVENTS in f:
        group = f[EVENTS]
        n = min(group[k].shape[0] for k in ("t_host_ns", "source", "text"))
        for t, source, text in zip(group["t_host_ns"][:n], group["source"][:n],
                                   group["text"][:n]):
            events.append({"t_host_ns": int(t), "source": source.decode(),
                           "text": text.decode("utf-8", "replace")})
    for name in stream_names(f):
        stream = read_stream(f, name)
        if stream.markers:
            events += [{"t_host_ns": int(t), "source": name, "text": " ".join(row)}
                       for t, row in zip(stream.t_host_ns, stream.text)]
    return sorted(events, key=lambda e: e["t_host_ns"])


def keep_consistent_rows(f: h5py.File) -> dict[str, int]:
    """Cut each extra stream of a recovered copy to its complete rows; rows dropped per stream."""
    dropped = {}
    for name in stream_names(f):
        group = f[GROUP][name]
        data_key = "text" if "text" in group else "values"
        n = _rows(group, data_key)
        longest = max(group[k].shape[0] for k in (data_key, "t_device_ns", "seq", "t_host_ns"))
        for key in (data_key, "t_device_ns", "seq", "t_host_ns"):
            group[key].resize(n, axis=0)
        dropped[name] = longest - n
    return dropped
