"""The rig config's ``[calib]`` table and the settings dataclasses filled from it.

The table's values, defaults included, are written once, in vbfe/default_rig.toml: the options
dataclasses declare their configurable fields with :func:`calib_field`, which takes the default
from there and says which key (and unit scale) sets the field."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal, Protocol, TypeVar

from vbfe.common.config import default_config
from vbfe.common.settings import limits, parse_table
from vbfe.drivers.registry import DeviceTables

T = TypeVar("T")
C = TypeVar("C", bound="CalibConfig")


@dataclass(frozen=True)
class CalibSettings:
    """Every key of the ``[calib]`` table, in its units, with its type and range; the values,
    defaults included, are those of vbfe/default_rig.toml (the one place they are written)."""

    target: Literal["charuco", "chessboard"]
    # a chessboard's (nx, ny), instead of its squares
    inner_corners: list[int] = dataclasses.field(metadata=limits())
    squares_x: int  # board values are checked by BoardSpec, with board-specific messages
    squares_y: int
    square_mm: float
    marker_mm: float
    dictionary: str
    legacy: bool
    calibration: str  # the rig's stereo calibration file ("": none settled)
    min_corners: int = dataclasses.field(metadata=limits(ge=4))
    min_views: int = dataclasses.field(metadata=limits(ge=1))
    outlier_sigma: float = dataclasses.field(metadata=limits(gt=0))
    outlier_min_px: float = dataclasses.field(metadata=limits(ge=0))
    view_outlier_z: float = dataclasses.field(metadata=limits(gt=0))
    view_outlier_min_px: float = dataclasses.field(metadata=limits(ge=0))
    well_determined_views: int = dataclasses.field(metadata=limits(ge=1))
    fix_k3: bool
    min_baseline_mm: float = dataclasses.field(metadata=limits(ge=0))
    nominal_baseline_mm: float = dataclasses.field(metadata=limits(ge=0))
    baseline_tolerance: float = dataclasses.field(metadata=limits(gt=0))
    max_rms_px: float = dataclasses.field(metadata=limits(gt=0))
    min_rectified_fraction: float = dataclasses.field(metadata=limits(ge=0, le=1))
    desync_min_px: float = dataclasses.field(metadata=limits(ge=0))
    reject_desync: bool
    rectify_alpha: float = dataclasses.field(metadata=limits(ge=-1, le=1))
    zero_disparity: Literal["auto", "on", "off"]
    working_distance_mm: float = dataclasses.field(metadata=limits(gt=0))
    capture_views: int = dataclasses.field(metadata=limits(ge=1))
    capture_max_views: int = dataclasses.field(metadata=limits(ge=1))
    min_sharpness: float = dataclasses.field(metadata=limits(ge=0))
    min_pose_distance: float = dataclasses.field(metadata=limits(ge=0))
    check_max_depth_error_mm: float = dataclasses.field(metadata=limits(gt=0))
    check_max_epipolar_px: float = dataclasses.field(metadata=limits(gt=0))
    projector_window_px: int = dataclasses.field(metadata=limits(ge=1))
    projector_min_contrast: float = dataclasses.field(metadata=limits(ge=0))
    projector_width: int = dataclasses.field(
        metadata=limits(ge=0)
    )  # 0: the projector size of the simulated rig
    projector_height: int = dataclasses.field(metadata=limits(ge=0))
    projector_settle_s: float = dataclasses.field(metadata=limits(ge=0))
    projector_still_level: float = dataclasses.field(metadata=limits(ge=0))
    projector_change_level: float = dataclasses.field(metadata=limits(ge=0))
    projector_still_frames: int = dataclasses.field(metadata=limits(ge=1))
    projector_pose_timeout_s: float = dataclasses.field(metadata=limits(gt=0))


class CalibConfig(DeviceTables, Protocol):
    """What calibrating reads of a rig configuration (:class:`vbfe.rig_config.RigConfig` is
    one): the device tables (its ``[calib]`` table for settings given as keys), the checked
    ``[calib]`` settings, and a copy with changed values (the bench's board scene)."""

    @property
    def calib(self) -> CalibSettings: ...

    def updated(self: C, changes: dict[str, dict[str, Any]], where: str = ...) -> C: ...


def calib_settings(calib_table: dict[str, Any]) -> CalibSettings:
    """The ``[calib]`` table over the built-in defaults, checked (unknown keys, wrong types and
    values out of range are a ConfigError)."""
    return parse_table(CalibSettings, {**_DEFAULT_TABLE, **calib_table}, "calib")


_DEFAULT_TABLE: dict[str, Any] = default_config()["calib"]
DEFAULTS = calib_settings({})


def calib_field(key: str, scale: float = 1.0) -> Any:
    """A dataclass field set by ``[calib] key`` (times ``scale``, e.g. 1e-3 for mm → m); its
    default is the key's value in vbfe/default_rig.toml."""
    value = getattr(DEFAULTS, key)
    metadata = {"calib_key": key, "scale": scale}
    if isinstance(value, list):
        return dataclasses.field(default_factory=lambda: list(value), metadata=metadata)
    return dataclasses.field(default=value * scale if scale != 1.0 else value, metadata=metadata)


def from_table(cls: type[T], table: dict[str, Any]) -> T:
    """An instance of dataclass ``cls`` whose :func:`calib_field` fields come from the
    ``[calib]`` table where it sets them (the whole table is checked first)."""
    checked = calib_settings(table)
    values = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        key = f.metadata.get("calib_key")
        if key is not None and key in table:
            value = getattr(checked, key)
            values[f.name] = value * f.metadata["scale"] if f.metadata["scale"] != 1.0 else value
    return cls(**values)


class CalibOptions:
    """A settings dataclass whose :func:`calib_field` fields the ``[calib]`` table sets."""

    @classmethod
    def from_config(cls: type[T], calib_table: dict[str, Any]) -> T:
        """Settings from a rig config's ``[calib]`` table (see :func:`from_table`)."""
        return from_table(cls, calib_table)
