"""Settings of a force-estimation training run (the ``[train]`` table of the rig config)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

from vbfe.estimate.errors import EstimateError
from vbfe.settings import parse_table, setting

TARGETS = ("magnitude", "xyz")
ROI_KINDS = ("all", "radius", "box")


@dataclass
class TrainConfig:
    """Everything that decides what a model sees and how it is trained.

    The region of interest (``roi``) is ``"all"`` finite points, ``"radius"`` (points within
    ``roi_radius_m`` of the cloud's per-frame median) or ``"box"`` (``roi_box_m`` =
    ``[xmin, ymin, zmin, xmax, ymax, zmax]`` in the rectified left-camera frame, metres).
    """

    epochs: int = setting(60, ge=1)
    batch_size: int = setting(32, ge=2)
    learning_rate: float = setting(1e-3, gt=0)
    n_points: int = setting(1024, ge=2)
    patience: int = setting(10, ge=1)
    target: Literal[TARGETS] = "magnitude"  # |F| in newtons, or the 3 trocar axes
    roi: Literal[ROI_KINDS] = "all"
    roi_radius_m: float = setting(0.02, gt=0)
    roi_box_m: list[float] = setting([-1.0, -1.0, 0.0, 1.0, 1.0, 1.0])
    pool_factor: int = setting(2, ge=1)  # points kept per frame = pool_factor * n_points
    frame_stride: int = setting(1, ge=1)  # use every k-th frame of each session
    val_fraction: float = setting(0.2, ge=0, lt=1)
    test_fraction: float = setting(0.0, ge=0, lt=1)
    seed: int = 0
    conv_channels: list[int] = setting([64, 128, 1024])
    head_channels: list[int] = setting([512, 256])
    dropout: float = setting(0.3, ge=0, lt=1)
    global_features: bool = True  # feed the removed centroid and D_max to the head
    time_limit_s: float = setting(0.0, ge=0)  # stop training after this wall time (0 = no limit)
    threads: int = setting(2, ge=1)  # torch CPU threads (1 is faster on shared cores)

    def __post_init__(self) -> None:
        if self.target not in TARGETS:
            raise EstimateError(f"[train] target must be one of {TARGETS}, not {self.target!r}")
        if self.roi not in ROI_KINDS:
            raise EstimateError(f"[train] roi must be one of {ROI_KINDS}, not {self.roi!r}")
        if len(self.roi_box_m) != 6:
            raise EstimateError("[train] roi_box_m needs 6 numbers: xmin ymin zmin xmax ymax zmax")
        if self.n_points < 2 or self.batch_size < 2 or self.epochs < 1:
            raise EstimateError("[train] needs n_points >= 2, batch_size >= 2 and epochs >= 1")
        if not 0 <= self.val_fraction < 1 or not 0 <= self.test_fraction < 1:
            raise EstimateError("[train] val_fraction and test_fraction must be in [0, 1)")

    @property
    def n_outputs(self) -> int:
        """Number of regressed force components."""
        return 1 if self.target == "magnitude" else 3

    @classmethod
    def from_table(cls, table: dict[str, Any], **overrides: Any) -> "TrainConfig":
        """Build from the rig config's ``[train]`` table, then apply non-``None`` overrides
        (checked like the table's keys)."""
        values = dict(table)
        values.update({k: v for k, v in overrides.items() if v is not None})
        return parse_table(cls, values, "train")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (stored in model files)."""
        return dataclasses.asdict(self)
