"""What an extra stream delivers: its description, and chunks of samples on the host clock."""

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
class StreamChunk:
    """Consecutive samples of one extra stream, as one record of the rig.

    ``values`` is ``(n, channels)`` float64, or str for marker streams; ``sample_t_device_ns``
    the source's own time stamps (its LSL ``local_clock()``), ``sample_t_host_ns`` the same
    instants on this host's monotonic clock (the stamps plus the stream's time correction).
    Like every record it has a ``seq`` (the index of its first sample since the stream was
    opened) and ``t_device_ns``/``t_host_ns`` (those of its last sample); ``corrections`` are
    the ``(t_host_ns, correction_ns)`` clock-offset measurements made since the previous chunk,
    ``t_received_ns`` when the chunk reached the driver."""

    stream: str
    values: np.ndarray
    sample_t_device_ns: np.ndarray
    sample_t_host_ns: np.ndarray
    seq: int
    t_received_ns: int
    corrections: tuple[tuple[int, int], ...] = ()

    def __len__(self) -> int:
        return len(self.sample_t_host_ns)

    @property
    def t_host_ns(self) -> int:
        """Host time of the last sample."""
        return int(self.sample_t_host_ns[-1])

    @property
    def t_device_ns(self) -> int:
        """Source time stamp of the last sample."""
        return int(self.sample_t_device_ns[-1])
