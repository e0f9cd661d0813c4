"""Settings of a force-estimation training run (the ``[train]`` table of the rig config)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from vbfe.common.errors import EstimateError
from vbfe.common.settings import parse_table, setting

AXES = ("x", "y", "z")
TARGETS = ("magnitude", "xyz", *AXES, *(f"-{a}" for a in AXES))
ROI_KINDS = ("all", "radius", "box")
SPLITS = ("session", "time")
# model choices: "auto" (best on validation) or one candidate (see ``candidates.py``)
MODELS = ("auto", "pointnet", "temporal", "ridge", "cnn", "ensemble", "hooke_texture")
DEVICES = ("auto", "cpu", "cuda")
INTERVAL_SCALES = ("none", "force")  # see ``intervals.py``


def _window(span_frames: int, n_frames: int) -> list[int]:
    """``n_frames`` offsets evenly spread from ``span_frames`` back to 0, oldest first."""
    return [int(v) for v in np.round(np.linspace(span_frames, 0, n_frames))]


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
    # |F| in newtons, "xyz": the three axes, or "x", "-z"...
    target: Literal[TARGETS] = "magnitude"  # type: ignore[valid-type]
    # a Literal of a tuple's values: the settings parser reads them; mypy cannot
    roi: Literal[ROI_KINDS] = "all"  # type: ignore[valid-type]
    roi_radius_m: float = setting(0.02, gt=0)
    roi_box_m: list[float] = setting([-1.0, -1.0, 0.0, 1.0, 1.0, 1.0])
    pool_factor: int = setting(2, ge=1)  # points kept per frame = pool_factor * n_points
    frame_stride: int = setting(1, ge=1)  # use every k-th frame of each session
    val_fraction: float = setting(0.2, ge=0, lt=1)
    test_fraction: float = setting(0.0, ge=0, lt=1)
    # "session": whole sessions per part; "time": ranges
    split: Literal[SPLITS] = "session"  # type: ignore[valid-type]
    gap_frames: int = setting(30, ge=0)  # frames left out at every boundary between parts
    train_frames: list[int] = setting([])  # time split: stated [start, stop) frame ranges
    val_frames: list[int] = setting([])
    test_frames: list[int] = setting([])
    folds: int = setting(0, ge=0)  # blocked cross-validation folds (0: none)
    # the model shipped: best on validation, or one forced
    model: Literal[MODELS] = "auto"  # type: ignore[valid-type]
    val_max_frames: int = setting(2048, ge=1)  # fixed validation subsample
    seed: int = 0
    conv_channels: list[int] = setting([64, 128, 1024])
    head_channels: list[int] = setting([512, 256])
    dropout: float = setting(0.3, ge=0, lt=1)
    global_features: bool = True  # feed the removed centroid and D_max to the head
    rest_depth: bool = True  # each point also carries its depth change vs the rest frame
    time_limit_s: float = setting(0.0, ge=0)  # guard: warn and stop a network's training
    # after this wall time (0 = no limit); training is otherwise the same on any machine
    threads: int = setting(2, ge=1)  # torch CPU threads while training (fixed: determinism)
    # "auto" (CUDA when torch sees it), "cpu" or "cuda"
    device: Literal[DEVICES] = "auto"  # type: ignore[valid-type]
    temporal_frames: int = setting(0, ge=0)  # temporal model: k frames in its causal window
    temporal_span_frames: int = setting(10, ge=1)  # oldest to newest frame of the window
    temporal_epochs: int = setting(0, ge=0)  # epochs of the temporal model (0: ``epochs``); it
    # starts from the trained PointNet's encoder, so it needs fewer
    # the temporal model's patience: it starts trained (PointNet's weights), and in the full
    # demos no epoch after its start beat it (10 epochs, 160 s, bought nothing)
    temporal_patience: int = setting(3, ge=1)
    image_cells: int = setting(32, ge=2)  # depth-change image: cells × cells over x, y
    ridge_sizes: list[int] = setting([4, 8, 16, 32])  # ridge thumbnails (divide image_cells)
    cnn_channels: list[int] = setting([8, 16, 32])  # small CNN on the depth-change image
    cnn_epochs: int = setting(40, ge=1)
    history_frames: int = setting(6, ge=0)  # displacement-history baseline: frames (0: off)
    history_span_frames: int = setting(20, ge=1)  # oldest to newest frame of its window
    interval_coverage: float = setting(0.9, gt=0, lt=1)  # prediction intervals' coverage
    # the intervals' width: constant ("none"), or growing with |F| ("force")
    interval_scale: Literal[INTERVAL_SCALES] = "none"  # type: ignore[valid-type]
    # selection (and the intervals' calibration) on the validation part needs this many frames
    # from at least two sessions; else on blocked folds of the training part (0: always on
    # the validation part)
    select_min_val_frames: int = setting(300, ge=0)
    # those blocked folds (sessions, or blocks in time); PointNet and the temporal model are
    # refitted on at most 3 (minutes per refit; each frame still held out once)
    select_folds: int = setting(5, ge=3)
    # with a validation part, the methods quick to refit (baselines, ridge, the CNN and its
    # ensemble, Hooke on the texture) calibrate their intervals on the out-of-fold residuals of
    # folds of the training and validation sessions, each holding out as many as validation
    interval_folds: bool = True
    # the networks stop early on the validation part's loss; false: they run every epoch
    # (the cosine schedule ends them) and the validation part only selects and calibrates
    early_stopping: bool = True

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
        for key, allowed in (
            ("split", SPLITS),
            ("device", DEVICES),
            ("interval_scale", INTERVAL_SCALES),
        ):
            if getattr(self, key) not in allowed:
                raise EstimateError(
                    f"[train] {key} must be one of {allowed}, not {getattr(self, key)!r}"
                )
        if self.model not in MODELS:
            raise EstimateError(f"[train] model must be one of {MODELS}, not {self.model!r}")
        if any(self.image_cells % size for size in self.ridge_sizes) or not self.ridge_sizes:
            raise EstimateError(
                f"[train] ridge_sizes {self.ridge_sizes} must divide image_cells {self.image_cells}"
            )
        for part in ("train", "val", "test"):
            stated = getattr(self, f"{part}_frames")
            if stated and (len(stated) != 2 or not 0 <= stated[0] < stated[1]):
                raise EstimateError(
                    f"[train] {part}_frames must be [start, stop) with 0 <= start < stop"
                )
        if (self.val_frames or self.test_frames) and not self.train_frames:
            raise EstimateError("stated frame ranges need the training range too (--train)")
        if self.folds in (1, 2):
            raise EstimateError(
                f"--folds {self.folds}: blocked cross-validation needs at least 3 "
                "folds (test, validation and training blocks), or 0 for none"
            )
        if self.train_frames and self.folds:
            raise EstimateError("give either frame ranges (--train/--val/--test) or --folds")
        for window in ("temporal", "history"):
            self._check_window(window)
        if self.temporal_epochs < 0:
            raise EstimateError("[train] temporal_epochs must be >= 0 (0: as many as epochs)")
        if self.val_max_frames < 1:
            raise EstimateError("[train] needs val_max_frames >= 1")
        for key in ("conv_channels", "head_channels", "cnn_channels"):
            widths = getattr(self, key)
            needs_one = key != "head_channels"
            if (needs_one and not widths) or any(w < 1 for w in widths):
                raise EstimateError(
                    f"[train] {key} = {widths}: give layer widths >= 1"
                    + (" (at least one layer)" if needs_one else "")
                )

    def _check_window(self, name: str) -> None:
        """A causal window (``{name}_frames`` over ``{name}_span_frames``) is off or >= 2 frames."""
        frames, span = getattr(self, f"{name}_frames"), getattr(self, f"{name}_span_frames")
        if frames < 0 or frames == 1 or (frames and span < frames - 1):
            raise EstimateError(
                f"[train] {name}_frames must be 0 (off) or >= 2, and "
                f"{name}_span_frames >= {name}_frames - 1"
            )

    @property
    def n_outputs(self) -> int:
        """Number of regressed force components."""
        return 3 if self.target == "xyz" else 1

    @property
    def temporal_window(self) -> list[int]:
        """Offsets (frames back from the newest) of the temporal model's window, oldest first."""
        return _window(self.temporal_span_frames, self.temporal_frames)

    @property
    def history_window(self) -> list[int]:
        """Offsets (frames back) of the displacement-history baseline's window, oldest first."""
        return _window(self.history_span_frames, self.history_frames)

    @classmethod
    def from_table(cls, table: dict[str, Any], **overrides: Any) -> TrainConfig:
        """Build from the rig config's ``[train]`` table, then apply non-``None`` overrides
        (checked like the table's keys)."""
        values = dict(table)
        values.update({k: v for k, v in overrides.items() if v is not None})
        return parse_table(cls, values, "train")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (stored in model files)."""
        return dataclasses.asdict(self)
