"""Settings of the rig config's ``[record]`` table: recording and the verify-sync limits."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Protocol

from vbfe.acquire.session.layout import COMPRESSIONS, DEFAULT_COMPRESSION
from vbfe.common.settings import parse_table, setting
from vbfe.drivers.registry import DeviceTables


@dataclass(frozen=True)
class RecordSettings:
    """The ``[record]`` table (see vbfe/default_rig.toml for what each key means)."""

    # a Literal of a tuple's values: the settings parser reads them; mypy cannot
    compression: Literal[COMPRESSIONS] = DEFAULT_COMPRESSION  # type: ignore[valid-type]
    flush_interval_s: float = setting(1.0, gt=0)
    queue_size: int = setting(64, ge=1)
    queue_mb: float = setting(512.0, ge=0)
    min_free_gb: float = setting(1.0, ge=0)
    tare_samples: int = setting(500, ge=1)
    sync_max_offset_s: float = setting(0.003, gt=0)
    sync_max_ci_halfwidth_s: float = setting(0.005, gt=0)
    sync_max_frame_drop: float = setting(0.05, ge=0, le=1)
    sync_max_force_drop: float = setting(0.05, ge=0, le=1)
    sync_exposure_s: float = setting(0.020, ge=0)
    sync_line_time_s: float = setting(0.0, ge=0)
    sync_projector_latency_s: float = setting(0.0, ge=0)
    frame_time_correction_s: float = 0.0


def record_settings(config: dict[str, dict[str, Any]]) -> RecordSettings:
    """The ``[record]`` table of a rig configuration, checked."""
    return parse_table(RecordSettings, config.get("record", {}), "record")


class RecordConfig(DeviceTables, Protocol):
    """What recording reads of a rig configuration (:class:`vbfe.rig_config.RigConfig` is
    one): the device tables, the ``[record]`` settings and the line saying which rig file it
    came from (stored in every session)."""

    @property
    def record(self) -> RecordSettings: ...

    def banner(self) -> str: ...
