"""The ``[live]`` table of the rig config."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Protocol

from vbfe.acquire.recording.settings import RecordConfig
from vbfe.common.settings import parse_table, setting
from vbfe.recon import SgbmParams


@dataclass(frozen=True)
class LiveSettings:
    """Defaults of ``vbfe live`` (see vbfe/default_rig.toml)."""

    scale: float = setting(1.0, ge=0.1, le=1.0)
    row_scale: float = setting(0.5, ge=0.1, le=1.0)
    verify: bool = True
    depth_margin_mm: float = setting(10.0, ge=0)  # search the rest's depths ± this (0: [recon]'s)
    device: Literal["auto", "cpu", "cuda"] = "auto"
    torch_threads: int = setting(1, ge=1)
    opencv_threads: int = setting(0, ge=0)  # 0: one per core
    status_interval_s: float = setting(1.0, gt=0)
    max_frame_age_s: float = setting(0.25, ge=0)  # later frames are skipped (0: no limit)
    model: str = ""  # the model file loaded when none is given ("": none settled)
    protocol: str = ""  # the method and interval of this protocol ("": traction's, pooled)


def live_settings(table: dict[str, Any]) -> LiveSettings:
    """The ``[live]`` table, checked."""
    return parse_table(LiveSettings, table, "live")


class LiveConfig(RecordConfig, Protocol):
    """What a live run reads of a rig configuration (:class:`vbfe.rig_config.RigConfig` is
    one): what a recording reads, the ``[live]`` settings and the ``[sgbm]`` matcher's."""

    @property
    def live(self) -> LiveSettings: ...

    @property
    def sgbm(self) -> SgbmParams: ...
