"""Per-frame training examples: ROI-cropped point clouds labelled with the trocar force.

Each session is prepared once (``prepare_session``): every used frame keeps a pool of
``pool_factor × n_points`` finite ROI points (drawn without replacement, or with replacement
when the ROI holds fewer), from which ``n_points`` are redrawn for each epoch. Frames whose ROI
holds fewer than ``MIN_FRAME_POINTS`` finite points, or whose force is not finite, are skipped
and counted. Splits are made by session, never by frame.
"""

from __future__ import annotations

import zlib
from collections import defaultdict
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from vbfe.estimate.displacement import DisplacementGrid
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.sources import SessionLike, condition_label, open_source
from vbfe.estimate.train_config import TrainConfig

MIN_FRAME_POINTS = 8

ProgressFn = Callable[[str, int, int], None]  # (stage, done, total)


def crop_roi(points: np.ndarray, config: TrainConfig) -> np.ndarray:
    """The finite points of a cloud inside the configured region of interest."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    if config.roi == "radius" and len(points):
        centre = np.median(points, axis=0)
        points = points[np.linalg.norm(points - centre, axis=1) <= config.roi_radius_m]
    elif config.roi == "box":
        box = np.asarray(config.roi_box_m, dtype=np.float64)
        points = points[np.all((points >= box[:3]) & (points <= box[3:]), axis=1)]
    return points


def sample_points(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points: without replacement when the cloud has enough, else with replacement."""
    index = rng.choice(len(points), size=n, replace=len(points) < n)
    return points[index]


def force_target(forces_n: np.ndarray, target: str) -> np.ndarray:
    """Regression target (frames × outputs): |F| or the three axes, newtons."""
    forces_n = np.asarray(forces_n, dtype=np.float64).reshape(-1, 3)
    if target == "magnitude":
        return np.linalg.norm(forces_n, axis=1, keepdims=True)
    return forces_n


@dataclass
class PreparedSession:
    """One session's usable frames, ready for training, evaluation and the baselines."""

    name: str
    conditions: dict[str, Any]
    times_ns: np.ndarray  # used frames, int64
    targets_n: np.ndarray  # used frames × outputs
    pools: np.ndarray  # used frames × pool × 3, float32, metres
    displacement_m: np.ndarray  # peak surface displacement vs the first usable frame
    n_frames_total: int
    n_skipped: int

    @property
    def condition(self) -> str:
        return condition_label(self.conditions)

    @property
    def n_used(self) -> int:
        return len(self.times_ns)


def prepare_session(item: SessionLike, config: TrainConfig) -> PreparedSession:
    """Read one session (path with clouds sidecar, or ``SessionClouds``) into a ``PreparedSession``."""
    source = open_source(item)
    try:
        forces = source.force_at_frames()
        times = source.frame_times_ns()
        targets = force_target(forces, config.target)
        rng = np.random.default_rng([config.seed, zlib.crc32(source.name.encode())])
        pool_size = config.pool_factor * config.n_points
        grid: DisplacementGrid | None = None
        kept, pools, displacement = [], [], []
        skipped = 0
        for i in range(source.n_frames):
            # the first usable frame is the displacement reference even when the stride skips it
            if i % config.frame_stride and grid is not None:
                continue
            points = crop_roi(source.cloud(i), config)
            cloud_ok = len(points) >= MIN_FRAME_POINTS
            if cloud_ok and grid is None:
                grid = DisplacementGrid(points)
            if i % config.frame_stride:
                continue
            if not cloud_ok or not np.isfinite(targets[i]).all():
                skipped += 1
                continue
            assert grid is not None
            kept.append(i)
            pools.append(sample_points(points, pool_size, rng).astype(np.float32))
            displacement.append(grid.peak_displacement_m(points))
        n_total = len(range(0, source.n_frames, config.frame_stride))
        return PreparedSession(
            name=source.name, conditions=dict(source.conditions),
            times_ns=np.asarray(times, dtype=np.int64)[kept], targets_n=targets[kept],
            pools=np.stack(pools) if pools else np.zeros((0, pool_size, 3), np.float32),
            displacement_m=np.asarray(displacement, dtype=np.float64),
            n_frames_total=n_total, n_skipped=skipped)
    finally:
        source.close()


def prepare_sessions(items: Sequence[SessionLike], config: TrainConfig,
                     progress: ProgressFn | None = None) -> list[PreparedSession]:
    """Prepare several sessions; an error names the session that has no usable frame."""
    prepared = []
    for k, item in enumerate(items):
        session = prepare_session(item, config)
        if session.n_used == 0:
            raise EstimateError(f"session {session.name} has no usable point cloud "
                                f"({session.n_skipped} empty/NaN frames): check the ROI in [train] "
                                "or run `vbfe reconstruct` again")
        prepared.append(session)
        if progress is not None:
            progress("sessions", k + 1, len(items))
    return prepared


def skipped_counts(sessions: Sequence[PreparedSession]) -> dict[str, dict[str, int]]:
    """Per session: frames considered, used and skipped (empty or NaN clouds)."""
    return {s.name: {"frames": s.n_frames_total, "used": s.n_used, "skipped": s.n_skipped}
            for s in sessions}


@dataclass
class SessionSplit:
    """Names of the sessions in each part; no session is in two parts."""

    train: list[str]
    val: list[str] = field(default_factory=list)
    test: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, list[str]]:
        return {"train": list(self.train), "val": list(self.val), "test": list(self.test)}


def split_by_session(sessions: Sequence[PreparedSession], val_fraction: float,
                     test_fraction: float, seed: int) -> SessionSplit:
    """Split sessions (not frames) into train/val/test, stratified by condition.

    Within each condition the sessions are shuffled and dealt round-robin so that every part
    gets its share of every condition when there are enough repeats; at least one session
    always stays in training.
    """
    rng = np.random.default_rng(seed)
    groups: dict[str, list[str]] = defaultdict(list)
    for s in sessions:
        groups[s.condition].append(s.name)
    ordered: list[str] = []
    for label in sorted(groups):
        names = list(groups[label])
        rng.shuffle(names)
        groups[label] = names
    # interleave conditions so that any prefix covers as many conditions as possible
    depth = max(len(v) for v in groups.values())
    for k in range(depth):
        ordered.extend(v[k] for _, v in sorted(groups.items()) if k < len(v))
    n = len(ordered)
    n_test = int(round(test_fraction * n))
    n_val = int(round(val_fraction * n))
    if n_val + n_test >= n:
        n_val = max(0, min(n_val, n - 1 - n_test))
        n_test = max(0, min(n_test, n - 1 - n_val))
    reversed_order = ordered[::-1]  # the last repeats of each condition go to val/test
    test = reversed_order[:n_test]
    val = reversed_order[n_test:n_test + n_val]
    train = [name for name in ordered if name not in set(test) | set(val)]
    return SessionSplit(train=train, val=val, test=test)


class FrameBatches:
    """The frames of some sessions as torch batches, with ``n_points`` redrawn from each pool."""

    def __init__(self, sessions: Sequence[PreparedSession], n_points: int) -> None:
        if not sessions:
            raise EstimateError("no sessions to draw frames from")
        self.pools = np.concatenate([s.pools for s in sessions])
        self.targets = np.concatenate([s.targets_n for s in sessions]).astype(np.float32)
        self.n_points = n_points

    def __len__(self) -> int:
        return len(self.pools)

    def draw(self, index: np.ndarray, rng: np.random.Generator | None) -> torch.Tensor:
        """Points (len(index) × n_points × 3) of the given frames; ``rng=None`` takes the first."""
        pools = self.pools[index]
        if rng is None:
            return torch.from_numpy(np.ascontiguousarray(pools[:, :self.n_points]))
        order = np.argsort(rng.random(pools.shape[:2]), axis=1)[:, :self.n_points]
        return torch.from_numpy(np.take_along_axis(pools, order[..., None], axis=1))

    def batches(self, batch_size: int, rng: np.random.Generator | None
                ) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """(points, targets) batches; shuffled with fresh points when ``rng`` is given."""
        order = rng.permutation(len(self)) if rng is not None else np.arange(len(self))
        for start in range(0, len(order), batch_size):
            index = order[start:start + batch_size]
            yield self.draw(index, rng), torch.from_numpy(self.targets[index])
