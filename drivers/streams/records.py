"""What an extra stream delivers: its description, and samples on the host clock."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class StreamInfo:
    """An extra stream as its source describes it (LSL stream info and XML metadata)."""

    name: str  # the session's name for it (the ``[streams]`` key)
    lsl_name: str
    type: str
    source_id: str
    hostname: str
    channels: tuple[str, ...]
    units: tuple[str, ...]  # "" where the metadata gives none
    nominal_rate_hz: float  # 0: irregular (event and marker streams)
    markers: bool  # string samples: event markers, stored in the session's event list
    info_xml: str = field(repr=False, default="")

    @property
    def n_channels(self) -> int:
        """Values per sample."""
        return len(self.channels)


@dataclass(frozen=True)
class StreamSample:
    """One sample of an extra stream: ``values`` (float64, one per channel) for a numeric
    stream, ``text`` for a marker stream (its channels joined by tabs); ``t_device_ns`` the
    publisher's time stamp (its LSL ``local_clock()``), ``t_host_ns`` the same instant on this
    host's clock (stamp plus the stream's time correction), ``seq`` its index since the
    stream was opened."""

    values: np.ndarray | None
    text: str | None
    seq: int
    t_device_ns: int
    t_host_ns: int
