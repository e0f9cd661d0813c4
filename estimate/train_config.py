"""Settings of a force-estimation training run (the ``[train]`` table of the rig config)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from vbfe.estimate.errors import EstimateError

TARGETS = ("magnitude", "xyz")
ROI_KINDS = ("all", "radius", "box")


@dataclass
class TrainConfig:
    """Everything that decides what a model sees and how it is trained.

    The region of interest (``roi``) is ``"all"`` finite points, ``"radius"`` (points within
    ``roi_radius_m`` of the cloud's per-frame median) or ``"box"`` (``roi_box_m`` =
    ``[xmin, ymin, zmin, xmax, ymax, zmax]`` in the rectified left-camera frame, metres).
    """

    epochs: int = 60
    batch_size: int = 32
    learning_rate: float = 1e-3
    n_points: int = 1024
    patience: int = 10
    target: str = "magnitude"  # |F| in newtons, or "xyz": the three trocar axes
    roi: str = "all"
    roi_radius_m: float = 0.02
    roi_box_m: list[float] = field(default_factory=lambda: [-1.0, -1.0, 0.0, 1.0, 1.0, 1.0])
    pool_factor: int = 2  # points kept per frame = pool_factor * n_points; redrawn every epoch
    frame_stride: int = 1  # use every k-th frame of each session
    val_fraction: float = 0.2
    test_fraction: float = 0.0
    seed: int = 0
    conv_channels: list[int] = field(default_factory=lambda: [64, 128, 1024])
    head_channels: list[int] = field(default_factory=lambda: [512, 256])
    dropout: float = 0.3
    global_features: bool = True  # feed the removed centroid and D_max to the head
    time_limit_s: float = 0.0  # stop training after this wall time (0 = no limit)
    threads: int = 2  # torch CPU threads (1 is faster when other jobs share the cores)

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
        """Build from the rig config's ``[train]`` table, then apply non-``None`` overrides."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise EstimateError(f"[train] has unknown key(s) {sorted(unknown)}; known: {sorted(known)}")
        values = dict(table)
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (stored in model files)."""
        return dataclasses.asdict(self)
