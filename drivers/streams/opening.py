"""The ``[streams]`` of a rig config as devices of the rig."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from vbfe.drivers.streams.lsl import LslStream
from vbfe.drivers.streams.settings import stream_sources


def streams_from_config(config: dict[str, dict[str, Any]]) -> dict[str, LslStream]:
    """The extra streams a rig config names, by session name (built, not opened; ConfigError
    when the table is wrong). Opening resolves them: a required one missing raises
    DeviceError naming it, an optional one stays unread (:func:`missing_streams`)."""
    return {source.key: LslStream(source) for source in stream_sources(config)}


def missing_streams(devices: Iterable[Any]) -> list[str]:
    """One warning per optional stream among opened ``devices`` that was not found."""
    return [d.missing for d in devices if isinstance(d, LslStream) and d.missing]
