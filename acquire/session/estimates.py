"""The ``/estimate`` stream of a session (schema 2): force estimated live from the frames.

``vbfe live --record`` stores one row per estimate: the force, the sequence number of the
frame it came from, that frame's host arrival time, the host time the estimate was ready, the
duration of each stage and, when the model has them, the estimate's prediction interval
(``lo_n``, ``hi_n``) and whether its frame was outside the training data (``ood``). Older
sessions have no such group, or no interval and flag.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from vbfe.common.errors import SessionError

GROUP = "estimate"


@dataclass
class EstimateStream:
    """The estimates stored in a session (one row each)."""

    force_n: np.ndarray  # (n, outputs) float64, NaN where a frame gave no usable cloud
    frame_seq: np.ndarray  # (n,) int64, camera sequence number of the source frame
    t_frame_host_ns: np.ndarray  # (n,) int64, host arrival of the source frame
    t_ready_host_ns: np.ndarray  # (n,) int64, host time the estimate was ready
    stage_s: np.ndarray  # (n, stages) float64
    stages: list[str]
    attrs: dict[str, Any]  # target, outputs, model, skipped_frames, …
    lo_n: np.ndarray | None = None  # (n, outputs) prediction interval (None: not stored)
    hi_n: np.ndarray | None = None
    ood: np.ndarray | None = None  # (n,) bool: the frame is outside the model's training data

    @property
    def latency_s(self) -> np.ndarray:
        """Frame arrival to estimate, seconds."""
        return (self.t_ready_host_ns - self.t_frame_host_ns) / 1e9

    def __len__(self) -> int:
        return len(self.frame_seq)


def write_estimates(f: h5py.File, stream: EstimateStream) -> None:
    """Write (or replace) the ``/estimate`` group in a session file open for writing."""
    n = len(stream)
    columns = {
        "force_n": (stream.force_n, "N"),
        "frame_seq": (stream.frame_seq, ""),
        "t_frame_host_ns": (stream.t_frame_host_ns, "ns"),
        "t_ready_host_ns": (stream.t_ready_host_ns, "ns"),
        "stage_s": (stream.stage_s, "s"),
    }
    for name, units in (("lo_n", "N"), ("hi_n", "N"), ("ood", "")):
        if getattr(stream, name) is not None:
            columns[name] = (getattr(stream, name), units)
    for name, (values, _) in columns.items():
        if len(values) != n:
            raise SessionError(f"estimate column {name} has {len(values)} rows, expected {n}")
    if GROUP in f:
        del f[GROUP]
    group = f.create_group(GROUP)
    for name, (values, units) in columns.items():
        ds = group.create_dataset(name, data=np.asarray(values), fletcher32=True)
        if units:
            ds.attrs["units"] = units
    group.attrs["stages"] = json.dumps(list(stream.stages))
    group.attrs["attrs_json"] = json.dumps(stream.attrs)


def read_estimates(f: h5py.File, path: Path) -> EstimateStream | None:
    """The ``/estimate`` group of an open session file, or ``None`` when it has none."""
    group = f.get(GROUP)
    if group is None:
        return None
    try:
        return EstimateStream(
            force_n=group["force_n"][()],
            frame_seq=group["frame_seq"][()],
            t_frame_host_ns=group["t_frame_host_ns"][()],
            t_ready_host_ns=group["t_ready_host_ns"][()],
            stage_s=group["stage_s"][()],
            stages=json.loads(group.attrs["stages"]),
            attrs=json.loads(group.attrs.get("attrs_json", "{}")),
            **{k: group[k][()] for k in ("lo_n", "hi_n", "ood") if k in group},
        )
    except (KeyError, OSError, ValueError) as exc:
        raise SessionError(
            f"the estimate stream of {path} is damaged ({exc}); it can be "
            f"recorded again with 'vbfe live --record'"
        ) from None
