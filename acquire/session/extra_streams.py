"""Extra streams in a session beyond the core ones: LSL streams of the rig (``[streams]``) and
the session's own event marks (``vbfe mark``), as rows of the layout table, and how they read
back."""

from __future__ import annotations

import json
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


@dataclass(frozen=True)
class StreamAccounting:
    """What happened to an extra stream's samples: ``lost`` (never received by the recorder:
    the inlet's buffer overflowed, or a full queue), and the publisher's own timing: stamp
    ``irregular_gaps`` (steps over 1.5 sample periods, ``missing_periods`` periods without a
    sample between them; nothing lost) and the ``worst_gap_ns`` step."""

    lost: int
    irregular_gaps: int
    missing_periods: int
    worst_gap_ns: int

    def text(self, received: int) -> str:
        """``lost 0 (0.00%); late/irregular publisher 1 gap, worst 201.0 ms``."""
        share = 100 * self.lost / max(received + self.lost, 1)
        late = (
            f"{self.irregular_gaps} gap{'s' if self.irregular_gaps != 1 else ''} "
            f"({self.missing_periods} sample periods without a sample), worst "
            f"{self.worst_gap_ns / 1e6:.1f} ms"
            if self.irregular_gaps
            else "none"
        )
        return f"lost {self.lost} ({share:.2f}%); late/irregular publisher {late}"


def stream_accounting(attrs: dict[str, Any], name: str) -> StreamAccounting:
    """The accounting of extra stream ``name`` from a finalized session's attributes (the
    recorder's drop counters and the device description at the end)."""
    lost = sum(int(attrs.get(f"{name}_{k}_dropped", 0)) for k in ("device", "queue"))
    devices = json.loads(attrs.get("devices_at_end_json") or "{}")
    timing = devices.get(name, {}).get("publisher_timing", {})
    return StreamAccounting(
        lost,
        int(timing.get("gaps", 0)),
        int(timing.get("missing_periods", 0)),
        int(timing.get("worst_gap_ns", 0)),
    )
