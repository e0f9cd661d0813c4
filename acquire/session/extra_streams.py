"""Extra streams in a session beyond the core ones: LSL streams of the rig (``[streams]``) and
the session's own event marks (``vbfe mark``), as rows of the layout table, and how they read
back."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vbfe.acquire.session.layout import TEXT, Column, StreamSpec, marker_stream
from vbfe.drivers.streams.records import StreamInfo

MARKS = "marks"  # the stream of event marks put into the session while recording


def marks_stream() -> StreamSpec:
    """Event marks (record attribute ``text``) stamped on the host clock."""
    return marker_stream(MARKS, clock="host")


def lsl_stream_spec(info: StreamInfo) -> StreamSpec:
    """The layout of one LSL stream: ``values`` (n × channels float64, attributes
    ``channels``, ``channel_units``) or, for a marker stream, ``text``; the stream's
    description (LSL name, type, source id, host, nominal rate, its XML) in the attributes."""
    described = (
        ("lsl_name", info.lsl_name),
        ("lsl_type", info.type),
        ("source_id", info.source_id),
        ("hostname", info.hostname),
        ("nominal_rate_hz", info.nominal_rate_hz),
        ("info_xml", info.info_xml),
    )
    if info.markers:
        return StreamSpec(info.name, (Column("text", TEXT, attrs=described),), chunk=64)
    units = set(info.units)
    return StreamSpec(
        info.name,
        (
            Column(
                "values",
                np.float64,
                (info.n_channels,),
                units.pop() if len(units) == 1 else "",
                (
                    ("channels", list(info.channels)),
                    ("channel_units", list(info.units)),
                    *described,
                ),
            ),
        ),
        chunk=int(min(4096, max(64, info.nominal_rate_hz))),
    )


@dataclass
class RecordedStream:
    """One extra stream as recorded: ``values`` (n × channels float64) or ``text`` (n, str);
    host times (``t_host_ns``) and the publisher's (``t_device_ns``); ``corrections``
    ``(t_host_ns, correction_ns)`` as measured while recording (finalized sessions); the
    stream's description (``lsl_name``, ``source_id``, ``nominal_rate_hz``, …) in ``attrs``."""

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
        """Whether this is a marker (text) stream."""
        return self.text is not None

    def __len__(self) -> int:
        return len(self.t_host_ns)
