"""The rig config's ``[streams]`` table: which extra streams a session records.

Each sub-table names one stream; its key is the stream's name in the session::

    [streams.robot]            # recorded as the session stream "robot"
    name = "KUKA-LBR-state"    # the LSL stream's name, type and/or source id (all given must match)
    required = true            # missing at start: the recording is refused (else a warning)
    buffer_s = 360.0           # how long the inlet keeps samples not yet read; past it the
                               # oldest are lost (counted as lost)
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Literal

from vbfe.common.errors import ConfigError
from vbfe.common.settings import parse_table, setting

RESERVED = (
    "camera",
    "force",
    "projector",
    "estimate",
    "marks",
    "gaps",
    "clock",
    "clock_pairs",
    "log",
    "truth",
    "analysis",
    "calibration_yaml",
)  # the session's own groups and datasets
_KEY = re.compile(r"[a-z][a-z0-9_]{0,31}")


@dataclass(frozen=True)
class StreamSource:
    """One ``[streams.<key>]`` table: how to find the stream and whether it must be there."""

    key: str = ""  # the session's name for the stream (the table's key; not a config key)
    backend: Literal["lsl"] = "lsl"
    name: str = ""
    type: str = ""
    source_id: str = ""
    required: bool = True
    resolve_timeout_s: float = setting(5.0, gt=0, le=600)
    buffer_s: float = setting(360.0, gt=0, le=3600)

    def predicate(self) -> str:
        """The LSL XPath predicate matching every property given."""
        parts = [
            f"{field}='{value}'"
            for field, value in (
                ("name", self.name),
                ("type", self.type),
                ("source_id", self.source_id),
            )
            if value
        ]
        return " and ".join(parts)

    def describe(self) -> str:
        """How messages name the stream: ``robot (LSL name='KUKA', type='State')``."""
        return f"{self.key} (LSL {self.predicate().replace(' and ', ', ')})"


def stream_sources(config: dict[str, dict[str, Any]]) -> list[StreamSource]:
    """The ``[streams]`` table of a rig config, checked (ConfigError naming table and key)."""
    sources = []
    for key, table in config.get("streams", {}).items():
        where = f"streams.{key}"
        if not isinstance(table, dict):
            raise ConfigError(
                f"[streams] {key} = {table!r} is not a table; write "
                f'[streams.{key}] with name = "<LSL stream name>"'
            )
        if not _KEY.fullmatch(key) or key in RESERVED:
            raise ConfigError(
                f"[{where}]: {key!r} cannot name a session stream; use lower-case "
                f"letters, digits and _ (not one of {', '.join(RESERVED)})"
            )
        if "key" in table:
            raise ConfigError(f"unknown key 'key' in [{where}]; the table's name is the key")
        source = parse_table(StreamSource, {**table, "key": key}, where)
        if not source.predicate():
            raise ConfigError(f"[{where}] names no stream: give its LSL name, type or source_id")
        for field, value in (
            ("name", source.name),
            ("type", source.type),
            ("source_id", source.source_id),
        ):
            if "'" in value:
                raise ConfigError(f"[{where}] {field} = {value!r} must not contain a quote")
        sources.append(source)
    return sources
