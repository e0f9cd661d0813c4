"""The rig config's ``[calib]`` table and the settings dataclasses filled from it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

from vbfe.settings import parse_table, setting

T = TypeVar("T")


@dataclass(frozen=True)
class CalibSettings:
    """Every key of the ``[calib]`` table, in its units (see vbfe/default_rig.toml)."""

    target: Literal["charuco", "chessboard"] = "charuco"
    inner_corners: list[int] = setting([])  # a chessboard's (nx, ny), instead of its squares
    squares_x: int = 9  # board values are checked by BoardSpec, with board-specific messages
    squares_y: int = 7
    square_mm: float = 3.0
    marker_mm: float = 2.2
    dictionary: str = "DICT_5X5_100"
    legacy: bool = False
    min_corners: int = setting(12, ge=4)
    min_views: int = setting(6, ge=1)
    outlier_sigma: float = setting(4.0, gt=0)
    outlier_min_px: float = setting(1.0, ge=0)
    view_outlier_z: float = setting(3.5, gt=0)
    view_outlier_min_px: float = setting(0.25, ge=0)
    well_determined_views: int = setting(10, ge=1)
    fix_k3: bool = False
    min_baseline_mm: float = setting(0.5, ge=0)
    nominal_baseline_mm: float = setting(4.0, ge=0)
    baseline_tolerance: float = setting(0.25, gt=0)
    max_rms_px: float = setting(1.0, gt=0)
    min_rectified_fraction: float = setting(0.5, ge=0, le=1)
    desync_min_px: float = setting(0.5, ge=0)
    reject_desync: bool = True
    rectify_alpha: float = setting(0.0, ge=0, le=1)
    working_distance_mm: float = setting(60.0, gt=0)
    capture_views: int = setting(20, ge=1)
    capture_max_views: int = setting(40, ge=1)
    min_sharpness: float = setting(12.0, ge=0)
    min_pose_distance: float = setting(0.2, ge=0)
    check_max_depth_error_mm: float = setting(0.5, gt=0)
    check_max_epipolar_px: float = setting(0.5, gt=0)
    projector_window_px: int = setting(8, ge=1)
    projector_min_contrast: float = setting(10.0, ge=0)
    projector_width: int = setting(0, ge=0)  # 0: the projector size of the simulated rig
    projector_height: int = setting(0, ge=0)
    projector_settle_s: float = setting(0.15, ge=0)
    projector_still_level: float = setting(2.0, ge=0)
    projector_change_level: float = setting(6.0, ge=0)
    projector_still_frames: int = setting(2, ge=1)
    projector_pose_timeout_s: float = setting(60.0, gt=0)


def calib_settings(calib_table: dict[str, Any]) -> CalibSettings:
    """The ``[calib]`` table, checked (unknown keys and wrong types are a ConfigError)."""
    return parse_table(CalibSettings, calib_table, "calib")


def from_table(cls: type[T], table: dict[str, Any], keys: dict[str, str] | None = None,
               scales: dict[str, float] | None = None) -> T:
    """An instance of dataclass ``cls`` whose fields come from the ``[calib]`` table where present.

    ``keys`` maps a field to its config key when the names differ; ``scales`` converts config
    units to the field's (e.g. mm → m: ``1e-3``). The whole table is checked first.
    """
    keys, scales = keys or {}, scales or {}
    checked = calib_settings(table)
    values = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        key = keys.get(f.name, f.name)
        if key in table:
            value = getattr(checked, key)
            values[f.name] = value * scales[f.name] if f.name in scales else value
    return cls(**values)
