"""The ``/estimate`` stream of a session (schema 2): force estimated live from the frames.

``vbfe live --record`` stores one row per estimate: the force, the sequence number of the
frame it came from, that frame's host arrival time, the host time the estimate was ready, the
duration of each stage and, when the model has them, the estimate's prediction interval
(``lo_n``, ``hi_n``) and whether its frame was outside the training data (``ood``). Older
sessions have no such group, or no interval and flag.

It is a stream of the session (:func:`estimate_stream_spec`, its time columns the host time
each estimate was ready), written as the estimates come and flushed with the frames, so a
recorder that dies keeps them up to its last flush; the run's counts are added to the group
when it ends. Sessions recorded before hold a plain group written at the end
(:func:`write_estimates`, also how estimates are added to a closed session).
"""

from __future__ import annotations

import json
import operator
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import h5py
import numpy as np

from vbfe.acquire.session.layout import Column, StreamSpec
from vbfe.common.errors import SessionError

GROUP = "estimate"
_SETTINGS = "attrs_json"  # the run's settings (target, model, …), then its counts at the end


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


class EstimateRecord(NamedTuple):
    """One estimate as a record of the session's ``/estimate`` stream: ``estimate`` has the
    stream's columns as attributes (a :class:`vbfe.live.estimator.LiveEstimate`); ``seq``
    counts the estimates of the run."""

    estimate: Any
    seq: int

    @property
    def t_host_ns(self) -> int:
        """When the estimate was ready (host clock)."""
        return int(self.estimate.t_ready_host_ns)

    @property
    def t_device_ns(self) -> int:
        """The estimator's clock is the host's."""
        return self.t_host_ns


def estimate_stream_spec(
    outputs: int, stages: Sequence[str], settings: dict[str, Any]
) -> StreamSpec:
    """The ``/estimate`` stream of :class:`EstimateRecord`\\ s: ``outputs`` force columns,
    the durations of ``stages``; ``settings`` (the model's target, …) stored with it."""

    def column(name: str, dtype: Any, shape: tuple[int, ...] = (), units: str = "", **attrs: Any):
        getter = operator.attrgetter(f"estimate.{name}")
        return Column(name, dtype, shape, units, tuple(attrs.items()), value=getter)

    return StreamSpec(
        GROUP,
        (
            column("force_n", np.float64, (outputs,), "N", **{_SETTINGS: json.dumps(settings)}),
            column("frame_seq", np.int64),
            column("t_frame_host_ns", np.int64, (), "ns"),
            column("stage_s", np.float64, (len(stages),), "s", stages=json.dumps(list(stages))),
            column("lo_n", np.float64, (outputs,), "N"),
            column("hi_n", np.float64, (outputs,), "N"),
            column("ood", np.bool_),
        ),
        chunk=256,
        clock="host",
    )


def finish_estimates(f: h5py.File, attrs: dict[str, Any]) -> None:
    """Add the run's counts ``attrs`` to the streamed ``/estimate`` of a closed session."""
    group = f[GROUP]
    settings = json.loads(group["force_n"].attrs[_SETTINGS])
    group.attrs[_SETTINGS] = json.dumps({**settings, **attrs})


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


def read_estimates(
    f: h5py.File, path: Path, recorded_seqs: np.ndarray, rows: int
) -> EstimateStream | None:
    """The ``/estimate`` group of an open session file, or ``None`` when it has none; of a
    streamed one, the first ``rows`` (those written whole) whose frame was recorded
    (``recorded_seqs``: a frame the recorder lost, or past the recording's end, keeps none)."""
    group = f.get(GROUP)
    if group is None:
        return None
    try:
        if "t_host_ns" not in group:  # written at the end (sessions of before)
            return EstimateStream(
                force_n=group["force_n"][()],
                frame_seq=group["frame_seq"][()],
                t_frame_host_ns=group["t_frame_host_ns"][()],
                t_ready_host_ns=group["t_ready_host_ns"][()],
                stage_s=group["stage_s"][()],
                stages=json.loads(group.attrs["stages"]),
                attrs=json.loads(group.attrs.get(_SETTINGS, "{}")),
                **{k: group[k][()] for k in ("lo_n", "hi_n", "ood") if k in group},
            )
        kept = np.isin(group["frame_seq"][:rows], recorded_seqs)
        return EstimateStream(
            force_n=group["force_n"][:rows][kept],
            frame_seq=group["frame_seq"][:rows][kept],
            t_frame_host_ns=group["t_frame_host_ns"][:rows][kept],
            t_ready_host_ns=group["t_host_ns"][:rows][kept],
            stage_s=group["stage_s"][:rows][kept],
            stages=json.loads(group["stage_s"].attrs["stages"]),
            attrs=json.loads(group.attrs.get(_SETTINGS, group["force_n"].attrs[_SETTINGS])),
            **{k: group[k][:rows][kept] for k in ("lo_n", "hi_n", "ood")},
        )
    except (KeyError, OSError, ValueError) as exc:
        raise SessionError(
            f"the estimate stream of {path} is damaged ({exc}); it can be "
            f"recorded again with 'vbfe live --record'"
        ) from None
