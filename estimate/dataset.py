"""Per-frame training examples: ROI-cropped point clouds labelled with the trocar force.

Each session is prepared once (``prepare_session``): every used frame keeps a pool of
``pool_factor × n_points`` finite ROI points (drawn without replacement, or with replacement
when the ROI holds fewer), from which ``n_points`` are redrawn for each epoch; with
``[train] rest_depth`` each point also carries its depth change against the session's first
usable frame (see ``rest_depth.py``). Frames whose ROI
holds fewer than ``MIN_FRAME_POINTS`` finite points, or whose force is not finite, are skipped
and counted. Splits are made by session (``split_by_session``) or by contiguous time blocks
inside each session with a gap between parts (``split_by_time``), never by single frames.
"""

from __future__ import annotations

import os
import zlib
from collections import defaultdict
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from vbfe.estimate.displacement import DisplacementGrid
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.rest_depth import RestDepth
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
    """Regression target (frames × outputs), newtons: |F|, the three axes, or one signed axis."""
    forces_n = np.asarray(forces_n, dtype=np.float64).reshape(-1, 3)
    if target == "magnitude":
        return np.linalg.norm(forces_n, axis=1, keepdims=True)
    if target == "xyz":
        return forces_n
    sign = -1.0 if target.startswith("-") else 1.0
    return sign * forces_n[:, "xyz".index(target[-1])][:, None]


@dataclass
class PreparedSession:
    """One session's usable frames, ready for training, evaluation and the baselines."""

    name: str
    conditions: dict[str, Any]
    times_ns: np.ndarray  # used frames, int64
    targets_n: np.ndarray  # used frames × outputs
    pools: np.ndarray  # used frames × pool × 3 (x, y, z; 4 with the rest depth change), float32, m
    displacement_m: np.ndarray  # peak surface displacement vs the first usable frame
    heights_m: np.ndarray  # used frames × cells²: depth change vs the first usable frame (0: unseen)
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
        # seeded by the session's file name, so a session draws the same pools from any folder
        rng = np.random.default_rng([config.seed,
                                     zlib.crc32(os.path.basename(source.name).encode())])
        pool_size = config.pool_factor * config.n_points
        grid: DisplacementGrid | None = None
        height_grid: DisplacementGrid | None = None
        rest: RestDepth | None = None
        kept, pools, displacement, heights = [], [], [], []
        skipped = 0
        for i in range(source.n_frames):
            # the first usable frame is the displacement reference even when the stride skips it
            if i % config.frame_stride and grid is not None:
                continue
            points = crop_roi(source.cloud(i), config)
            cloud_ok = len(points) >= MIN_FRAME_POINTS
            if cloud_ok and grid is None:
                grid = DisplacementGrid(points)
                height_grid = DisplacementGrid(points, cells=config.ridge_cells)
                rest = RestDepth(points) if config.rest_depth else None
            if i % config.frame_stride:
                continue
            if not cloud_ok or not np.isfinite(targets[i]).all():
                skipped += 1
                continue
            assert grid is not None and height_grid is not None
            kept.append(i)
            pool = sample_points(points, pool_size, rng)
            pools.append(rest.with_change(pool) if rest else pool.astype(np.float32))
            displacement.append(grid.peak_displacement_m(points))
            heights.append(np.nan_to_num(height_grid.depth_map(points)
                                         - height_grid.reference_depth_m).ravel())
        n_total = len(range(0, source.n_frames, config.frame_stride))
        return PreparedSession(
            name=source.name, conditions=dict(source.conditions),
            times_ns=np.asarray(times, dtype=np.int64)[kept], targets_n=targets[kept],
            pools=(np.stack(pools) if pools else
                   np.zeros((0, pool_size, 4 if config.rest_depth else 3), np.float32)),
            displacement_m=np.asarray(displacement, dtype=np.float64),
            heights_m=np.asarray(heights, dtype=np.float64).reshape(len(kept),
                                                                    config.ridge_cells ** 2),
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


PARTS = ("train", "val", "test")


def _session_key(name: str) -> str:
    """A session's identity: its resolved path when it names a file, else the name."""
    return os.path.realpath(name) if os.path.exists(name) else name


@dataclass
class SessionSplit:
    """Which frames are in each part: whole sessions (``kind="session"``) or, for
    ``kind="time"``, blocks of used-frame positions ``[start, stop)`` per session and part.

    ``train``/``val``/``test`` name the sessions that have frames in each part.
    """

    train: list[str]
    val: list[str] = field(default_factory=list)
    test: list[str] = field(default_factory=list)
    kind: str = "session"
    gap_frames: int = 0
    blocks: dict[str, dict[str, list[list[int]]]] = field(default_factory=dict)

    def _find(self, name: str, names: Sequence[str]) -> str | None:
        """The entry of ``names`` that is session ``name`` (the same file by another path)."""
        key = _session_key(name)
        return next((n for n in names if _session_key(n) == key), None)

    def contains(self, part: str, name: str) -> bool:
        """Whether session ``name`` has frames in ``part``."""
        return self._find(name, getattr(self, part)) is not None

    def positions(self, part: str, session: PreparedSession) -> np.ndarray:
        """Used-frame positions of ``session`` that belong to ``part`` (may be empty)."""
        found = self._find(session.name, getattr(self, part))
        if found is None:
            return np.zeros(0, dtype=np.int64)
        if self.kind == "time":
            ranges = self.blocks[part][found]
            return np.concatenate([np.arange(a, b) for a, b in ranges])
        return np.arange(session.n_used)

    def frames(self, part: str, sessions: Sequence[PreparedSession]
               ) -> list[tuple[PreparedSession, np.ndarray]]:
        """(session, positions) of every session with frames in ``part``."""
        picked = [(s, self.positions(part, s)) for s in sessions]
        return [(s, p) for s, p in picked if len(p)]

    def describe(self) -> str:
        """One line for reports: the kind of split, its gap and the parts' sizes."""
        if self.kind == "session":
            return (f"split by session: {len(self.train)} train, {len(self.val)} validation, "
                    f"{len(self.test)} test session(s)")
        counts = {part: sum(b - a for ranges in self.blocks.get(part, {}).values()
                            for a, b in ranges) for part in PARTS}
        return (f"split by time blocks inside sessions, gap {self.gap_frames} frames: "
                f"{counts['train']} train, {counts['val']} validation, {counts['test']} test "
                "frames")

    def to_dict(self) -> dict[str, Any]:
        return {"train": list(self.train), "val": list(self.val), "test": list(self.test),
                "kind": self.kind, "gap_frames": self.gap_frames, "blocks": self.blocks}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "SessionSplit":
        return cls(train=list(d.get("train", [])), val=list(d.get("val", [])),
                   test=list(d.get("test", [])), kind=d.get("kind", "session"),
                   gap_frames=int(d.get("gap_frames", 0)), blocks=d.get("blocks", {}))


def split_sessions(sessions: Sequence[PreparedSession], config: TrainConfig) -> SessionSplit:
    """The split ``config.split`` asks for."""
    if config.split == "time":
        return split_by_time(sessions, config.val_fraction, config.test_fraction,
                             config.time_blocks, config.gap_frames, config.seed)
    return split_by_session(sessions, config.val_fraction, config.test_fraction, config.seed)


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


def _ranges(mask: np.ndarray) -> list[list[int]]:
    """``[start, stop)`` runs of True in a boolean array."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return [[int(a), int(b)] for a, b in zip(edges[::2], edges[1::2])]


def split_by_time(sessions: Sequence[PreparedSession], val_fraction: float, test_fraction: float,
                  n_blocks: int, gap_frames: int, seed: int) -> SessionSplit:
    """Split each session into ``n_blocks`` contiguous time blocks dealt to train/val/test.

    Per session, ``round(fraction × n_blocks)`` blocks (chosen at random with ``seed``) go to
    validation and test, the rest to training (at least one block). At every boundary
    between parts, ``gap_frames`` frames on the side of the lower part (train < val < test) are
    left out of every part, so no frame used for fitting lies within the gap of a held-out one.
    """
    n_test = int(round(test_fraction * n_blocks))
    n_val = min(int(round(val_fraction * n_blocks)), n_blocks - 1 - n_test)
    if n_test > n_blocks - 1:
        raise EstimateError(f"test_fraction {test_fraction} leaves no training block of "
                            f"{n_blocks}; lower it or raise time_blocks")
    rng = np.random.default_rng(seed)
    blocks: dict[str, dict[str, list[list[int]]]] = {part: {} for part in PARTS}
    for s in sessions:
        label = np.zeros(n_blocks, dtype=np.int64)
        chosen = rng.permutation(n_blocks)
        label[chosen[:n_test]] = 2
        label[chosen[n_test:n_test + n_val]] = 1
        bounds = np.linspace(0, s.n_used, n_blocks + 1).astype(int)
        part = np.repeat(label, np.diff(bounds))
        keep = np.ones(s.n_used, dtype=bool)
        for b in bounds[1:-1]:
            left, right = part[b - 1], part[min(b, s.n_used - 1)]
            if left < right:
                keep[max(b - gap_frames, 0):b] &= part[max(b - gap_frames, 0):b] != left
            elif right < left:
                keep[b:b + gap_frames] &= part[b:b + gap_frames] != right
        for k, name in enumerate(PARTS):
            ranges = _ranges((part == k) & keep)
            if ranges:
                blocks[name][s.name] = ranges
    return SessionSplit(train=list(blocks["train"]), val=list(blocks["val"]),
                        test=list(blocks["test"]), kind="time", gap_frames=gap_frames,
                        blocks=blocks)


class FrameBatches:
    """Frames of some sessions as torch batches, with ``n_points`` redrawn from each pool.

    ``parts`` are (session, used-frame positions) pairs. With a ``window`` (offsets back in
    frames, oldest first, e.g. ``[10, 5, 0]``) each example is the causal window of those
    frames preceded by the session's rest (first) frame: ``B × (1 + k) × n_points × C``;
    frames before the session start repeat its first frame. ``max_frames`` keeps a fixed,
    evenly spaced subsample (e.g. for validation).
    """

    def __init__(self, parts: Sequence[tuple[PreparedSession, np.ndarray]], n_points: int,
                 window: Sequence[int] = (), max_frames: int | None = None) -> None:
        if not parts:
            raise EstimateError("no sessions to draw frames from")
        self.pools = np.concatenate([s.pools for s, _ in parts])
        starts = np.cumsum([0] + [s.n_used for s, _ in parts[:-1]])
        self.frames = np.concatenate([start + np.asarray(p, np.int64)
                                      for start, (_, p) in zip(starts, parts)])
        self.first = np.concatenate([np.full(len(p), start, np.int64)
                                     for start, (_, p) in zip(starts, parts)])
        if max_frames is not None and len(self.frames) > max_frames:
            keep = np.linspace(0, len(self.frames) - 1, max_frames).round().astype(int)
            self.frames, self.first = self.frames[keep], self.first[keep]
        targets = np.concatenate([s.targets_n for s, _ in parts]).astype(np.float32)
        self.targets = targets[self.frames]
        self.window = np.asarray(window, dtype=np.int64)
        self.n_points = n_points

    def __len__(self) -> int:
        return len(self.frames)

    def frame_indices(self, index: np.ndarray) -> np.ndarray:
        """Rows of ``pools`` for examples ``index``: (B,) or, with a window, (B, 1 + k)."""
        current = self.frames[index]
        if not len(self.window):
            return current
        first = self.first[index][:, None]
        history = np.maximum(current[:, None] - self.window[None], first)
        return np.concatenate([first, history], axis=1)

    def draw(self, index: np.ndarray, rng: np.random.Generator | None) -> torch.Tensor:
        """Points of the given examples; ``rng=None`` takes each pool's first ``n_points``."""
        pools = self.pools[self.frame_indices(index)]
        if rng is None:
            return torch.from_numpy(np.ascontiguousarray(pools[..., :self.n_points, :]))
        order = np.argsort(rng.random(pools.shape[:-1]), axis=-1)[..., :self.n_points]
        return torch.from_numpy(np.take_along_axis(pools, order[..., None], axis=-2))

    def batches(self, batch_size: int, rng: np.random.Generator | None
                ) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """(points, targets) batches; shuffled with fresh points when ``rng`` is given."""
        order = rng.permutation(len(self)) if rng is not None else np.arange(len(self))
        for start in range(0, len(order), batch_size):
            index = order[start:start + batch_size]
            yield self.draw(index, rng), torch.from_numpy(self.targets[index])
