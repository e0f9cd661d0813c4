"""Names and codes of the HDF5 session layout (schema documented in docs/session-format.md)."""

from __future__ import annotations

import hdf5plugin

FORMAT_NAME = "vbfe-session"
SCHEMA_VERSION = 2  # 2: optional /estimate stream (vbfe live --record)

COMPRESSIONS = ("none", "lzf", "blosc-lz4", "mjpeg")
STREAMS = ("camera", "force", "projector")  # also the names of their HDF5 groups
GAP_REASONS = ("queue full", "device disconnected", "device error", "bus state change")
GAP_COLUMNS = ("stream", "reason", "last_seq", "next_seq", "t_host_ns", "count")
PATTERN_NAME_DTYPE = "S64"
JPEG_QUALITY = 95


def image_filter(compression: str) -> dict:
    """h5py ``create_dataset`` keywords for raw image chunks under a compression option."""
    if compression == "none" or compression == "mjpeg":
        return {}
    if compression == "lzf":
        return {"compression": "lzf"}
    if compression == "blosc-lz4":
        return dict(hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE))
    raise ValueError(f"unknown compression {compression!r}; choose one of {COMPRESSIONS}")
