"""The HDF5 session layout as one table of streams (schema documented in
docs/reference/session-format.md): it drives creation (writer), checking (reader), trimming
(recovery) and the end-of-recording clock fits.

A stream is one HDF5 group of equally long datasets, one row per record: the time columns
``t_device_ns`` (the device's clock, see ``clock``), ``t_host_ns`` and ``seq`` (``int64``),
then its data :class:`Column`\\ s. Variable-length payloads (the camera's JPEG bytes) are
``blobs``: one byte dataset per blob, rows found through the ``<blob>_index`` column
(offset, length). The three core streams are in every session; a session may hold further
streams (e.g. LSL robot kinematics or markers): their specs are stored in the file
(:data:`EXTRA_STREAMS_ATTR`) so readers check and recovery trims them like the core ones.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import h5py
import hdf5plugin
import numpy as np

from vbfe.acquire.session.deflate import write_deflated

SCHEMA_VERSION = 2  # 2: optional /estimate stream (vbfe live --record)

CAMERA, FORCE, PROJECTOR = "camera", "force", "projector"  # the core streams' names
STREAMS = (CAMERA, FORCE, PROJECTOR)  # the core streams (also their HDF5 groups)
TIME_COLUMNS = ("t_device_ns", "t_host_ns", "seq")
GAP_REASONS = ("queue full", "device disconnected", "device error", "bus state change")
GAP_COLUMNS = ("stream", "reason", "last_seq", "next_seq", "t_host_ns", "count")
PATTERN_NAME_DTYPE = "S64"
JPEG_QUALITY = 95
LOG = "log"  # the recording's log lines (text, one per row; sessions from before have none)
EXTRA_STREAMS_ATTR = "extra_streams_json"  # root attribute: the specs of non-core streams
TEXT = h5py.string_dtype()  # dtype of a text column (e.g. LSL string markers)


@dataclass(frozen=True)
class Column:
    """A dataset of a stream: one value of ``shape`` per record.

    ``value(record)`` gives it (default: the record's attribute ``name``); ``chunk`` overrides
    the stream's rows per chunk; ``image`` columns take the session's image compression."""

    name: str
    dtype: Any
    shape: tuple[int, ...] = ()
    units: str = ""
    attrs: tuple[tuple[str, Any], ...] = ()
    value: Callable[[Any], Any] | None = field(default=None, compare=False)
    chunk: int | None = None
    image: bool = False

    def values(self, records: Sequence[Any]) -> np.ndarray:
        """The column's values of ``records`` as one array."""
        get = self.value or (lambda r: getattr(r, self.name))
        return np.array([get(r) for r in records], dtype=self.dtype).reshape(
            len(records), *self.shape
        )

    def kind(self) -> str:
        """The dtype kind a reader accepts for it."""
        return "T" if h5py.check_string_dtype(np.dtype(self.dtype)) else np.dtype(self.dtype).kind

    def describe(self) -> dict[str, Any]:
        """JSON-able spec (what a reader needs to check it)."""
        return {
            "name": self.name,
            "dtype": "text" if self.kind() == "T" else np.dtype(self.dtype).str,
            "shape": list(self.shape),
            "units": self.units,
        }


@dataclass(frozen=True)
class StreamSpec:
    """A stream: its group ``name``, data ``columns``, ``blobs``, rows per ``chunk``, and what
    ``t_device_ns`` counts (``clock``: "device" for the device's own clock, fitted to the host
    clock at the end; "host" when the device has none)."""

    name: str
    columns: tuple[Column, ...]
    chunk: int = 4096
    clock: str = "device"
    blobs: tuple[str, ...] = ()

    def keys(self) -> list[str]:
        """Every per-record dataset of the stream (time columns first)."""
        return [*TIME_COLUMNS, *(c.name for c in self.columns)]

    def datasets(self) -> list[tuple[str, int, str]]:
        """``(path, dimensions, dtype kind)`` of each dataset, for readers to check."""
        out = [(f"{self.name}/{k}", 1, "i") for k in TIME_COLUMNS]
        out += [(f"{self.name}/{c.name}", 1 + len(c.shape), c.kind()) for c in self.columns]
        out += [(f"{self.name}/{b}", 1, "u") for b in self.blobs]
        return out

    def describe(self) -> dict[str, Any]:
        """JSON-able spec, stored in sessions for streams beyond the core ones."""
        return {
            "name": self.name,
            "chunk": self.chunk,
            "clock": self.clock,
            "columns": [c.describe() for c in self.columns],
        }

    @classmethod
    def from_description(cls, d: dict[str, Any]) -> StreamSpec:
        """The spec :meth:`describe` stored (without value getters: for reading)."""
        columns = tuple(
            Column(
                c["name"],
                TEXT if c["dtype"] == "text" else np.dtype(c["dtype"]),
                tuple(c["shape"]),
                c.get("units", ""),
            )
            for c in d["columns"]
        )
        return cls(d["name"], columns, int(d.get("chunk", 4096)), d.get("clock", "device"))


def vector_stream(
    name: str, channels: Sequence[str], units: str = "", clock: str = "device"
) -> StreamSpec:
    """A stream of N float channels per record (record attribute ``values``), e.g. robot
    kinematics from LSL."""
    return StreamSpec(
        name,
        (Column("values", np.float64, (len(channels),), units, (("channels", list(channels)),)),),
        clock=clock,
    )


def marker_stream(name: str, clock: str = "device") -> StreamSpec:
    """A stream of text markers (record attribute ``text``)."""
    return StreamSpec(name, (Column("text", TEXT),), chunk=64, clock=clock)


def core_streams(
    frame_size: tuple[int, int], encoding: str, force_axes: Sequence[str]
) -> tuple[StreamSpec, ...]:
    """The camera (``raw`` or ``jpeg`` images), force and projector streams."""
    width, height = frame_size
    if encoding == "jpeg":
        images = tuple(
            Column(
                f"{eye}_jpeg_index", np.int64, (2,), "byte", (("columns", ["offset", "length"]),)
            )
            for eye in ("left", "right")
        )
        blobs: tuple[str, ...] = ("left_jpeg", "right_jpeg")
    else:
        images = tuple(
            Column(eye, np.uint8, (height, width, 3), chunk=1, image=True)
            for eye in ("left", "right")
        )
        blobs = ()
    camera = StreamSpec(CAMERA, images, chunk=256, blobs=blobs)
    force = StreamSpec(
        FORCE,
        (Column("force_n", np.float64, (len(force_axes),), "N", (("axes", list(force_axes)),)),),
    )
    projector = StreamSpec(
        PROJECTOR,
        (
            Column("pattern", PATTERN_NAME_DTYPE, value=lambda e: e.pattern.encode()[:64]),
            Column("frame_id", np.int64),
        ),
        chunk=64,
    )
    return camera, force, projector


def extra_streams(attrs: Any) -> tuple[StreamSpec, ...]:
    """The non-core streams a session file declares (root attributes)."""
    raw = attrs.get(EXTRA_STREAMS_ATTR)
    if raw is None:
        return ()
    return tuple(StreamSpec.from_description(d) for d in json.loads(raw))


def session_streams(f: h5py.File) -> tuple[StreamSpec, ...]:
    """Every stream of an open session file, from its camera group and declarations."""
    camera = f[CAMERA]
    size = (int(camera.attrs.get("width", 0)), int(camera.attrs.get("height", 0)))
    force = f.get("force/force_n")
    axes = (
        [str(a) for a in force.attrs.get("axes", ["x", "y", "z"])]
        if force is not None
        else ["x", "y", "z"]
    )
    encoding = str(camera.attrs.get("encoding", "raw"))
    return (*core_streams(size, encoding, axes), *extra_streams(f.attrs))


@dataclass(frozen=True)
class ImageCodec:
    """How a session stores its camera images: the HDF5 filter of the raw-pixel datasets
    (``keywords``: h5py ``create_dataset`` keywords), who can read them, and (``write_row``)
    a writer of one image row cheaper than HDF5's own filter, where there is one (its last
    argument: the writer is behind, spend the least CPU the filter allows)."""

    name: str
    keywords: Callable[[], dict[str, Any]]
    reach: str  # who decodes it: "stock HDF5", "with plugin" or "h5py only"
    readers: str
    write_row: Callable[[h5py.Dataset, int, np.ndarray, bool], None] | None = None


def _no_filter() -> dict[str, Any]:
    return {}


IMAGE_CODECS = {
    codec.name: codec
    for codec in (
        ImageCodec(
            "gzip",
            lambda: {"compression": "gzip", "compression_opts": 1},
            "stock HDF5",
            "every HDF5 reader (deflate is built into HDF5: MATLAB, HDFView, h5dump, h5py)",
            write_deflated,
        ),
        ImageCodec("none", _no_filter, "stock HDF5", "every HDF5 reader"),
        ImageCodec(
            "zstd",
            lambda: dict(hdf5plugin.Zstd(clevel=1)),
            "with plugin",
            "h5py with hdf5plugin; MATLAB, HDFView and h5dump with HDF5_PLUGIN_PATH set to "
            "hdf5plugin's plugin folder (filter 32015)",
        ),
        ImageCodec(
            "blosc-lz4",
            lambda: dict(hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE)),
            "with plugin",
            "h5py with hdf5plugin; MATLAB, HDFView and h5dump with HDF5_PLUGIN_PATH set to "
            "hdf5plugin's plugin folder (filter 32001)",
        ),
        ImageCodec(
            "lzf",
            lambda: {"compression": "lzf"},
            "h5py only",
            "h5py only (filter 32000 ships with h5py; other readers need it built as a plugin)",
        ),
        ImageCodec(
            "mjpeg",
            _no_filter,
            "stock HDF5",
            "every HDF5 reader reads the JPEG bytes (left_jpeg + left_jpeg_index); decode them "
            "with any JPEG decoder",
        ),
    )
}
COMPRESSIONS = tuple(IMAGE_CODECS)  # the names a session's ``compression`` may take
DEFAULT_COMPRESSION = "gzip"  # chosen by benchmarks/bench_record.py (docs: session format)


def image_filter(compression: str) -> dict[str, Any]:
    """h5py ``create_dataset`` keywords for raw image chunks under a compression option."""
    codec = IMAGE_CODECS.get(compression)
    if codec is None:
        raise ValueError(f"unknown compression {compression!r}; choose one of {COMPRESSIONS}")
    return codec.keywords()
