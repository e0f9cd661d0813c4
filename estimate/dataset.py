"""Per-frame training examples: each session's frames as features labelled with the force.

Each session is prepared once (``prepare_session``) with the same ``FramePreparer`` that
``vbfe live`` uses (``preparation.py``), against the session's first usable frame: every used
frame keeps a pool of ``pool_factor × n_points`` ROI points (from which ``n_points`` are
redrawn for each epoch), its peak displacement and its depth-change image. Frames whose ROI
holds fewer than ``MIN_FRAME_POINTS`` finite points, and frames without a finite force, are
skipped and counted apart. ``FrameBatches`` serves the pools as torch batches.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
import zlib
from collections.abc import Callable, Generator, Iterator, Sequence
from dataclasses import dataclass
from itertools import repeat
from typing import Any

import numpy as np
import torch

from vbfe.common.errors import EstimateError
from vbfe.common.signals import stop_pool_on_signals
from vbfe.estimate.preparation import FrameFeatures, FramePreparer, force_target
from vbfe.estimate.sources import SessionLike, condition_label, open_source
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.workers import WORKER_START_S, spawn_pool

ProgressFn = Callable[[str, int, int], None]  # (stage, done, total)

log = logging.getLogger(__name__)

DEFAULT_PROTOCOL = "traction"  # the paper's pull and hold: a session stating no protocol


@dataclass
class PreparedSession:
    """One session's usable frames, ready for training, evaluation and the baselines."""

    name: str
    conditions: dict[str, Any]
    frame_index: np.ndarray  # the session's frame number of each used frame, int64
    times_ns: np.ndarray  # used frames, int64
    targets_n: np.ndarray  # used frames × outputs
    pools: np.ndarray  # used frames × pool × 3 (x, y, z; 4 with the rest depth change), float32, m
    displacement_m: np.ndarray  # peak surface displacement vs the first usable frame
    texture_displacement_m: np.ndarray  # peak 3D displacement in the texture (NaN: none)
    image_sum: np.ndarray  # used frames × cells × cells: summed depth change vs rest (m)
    image_count: np.ndarray  # used frames × cells × cells: points per cell
    n_frames_total: int
    n_no_cloud: int  # frames whose ROI holds too few points
    n_no_force: int  # frames without a finite force

    @property
    def condition(self) -> str:
        return condition_label(self.conditions)

    @property
    def protocol(self) -> str:
        """What the operator did: ``"freehand"``, …; :data:`DEFAULT_PROTOCOL` unless the
        session's conditions state another."""
        return str(self.conditions.get("protocol", DEFAULT_PROTOCOL))

    @property
    def n_used(self) -> int:
        return len(self.times_ns)

    @property
    def n_skipped(self) -> int:
        return self.n_no_cloud + self.n_no_force

    @classmethod
    def from_features(
        cls,
        name: str,
        conditions: dict[str, Any],
        features: Sequence[FrameFeatures],
        frame_index: np.ndarray,
        times_ns: np.ndarray,
        targets_n: np.ndarray,
        config: TrainConfig,
        n_frames_total: int,
        n_no_cloud: int = 0,
        n_no_force: int = 0,
    ) -> PreparedSession:
        """A session from its used frames' features (``FramePreparer.features``)."""
        cells, channels = config.image_cells, 4 if config.rest_depth else 3
        pool = config.pool_factor * config.n_points

        def stacked(key: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
            return np.asarray([getattr(f, key) for f in features], dtype).reshape(-1, *shape)

        return cls(
            name=name,
            conditions=conditions,
            frame_index=frame_index,
            times_ns=np.asarray(times_ns, np.int64),
            targets_n=targets_n,
            pools=(
                np.stack([f.pool for f in features])
                if len(features)
                else np.zeros((0, pool, channels), np.float32)
            ),
            displacement_m=stacked("displacement_m", (), np.float64),
            texture_displacement_m=stacked("texture_displacement_m", (), np.float64),
            image_sum=stacked("image_sum", (cells, cells), np.float32),
            image_count=stacked("image_count", (cells, cells), np.float32),
            n_frames_total=n_frames_total,
            n_no_cloud=n_no_cloud,
            n_no_force=n_no_force,
        )


def prepare_session(
    item: SessionLike, config: TrainConfig, texture: bool = True
) -> PreparedSession:
    """Read one session (path with clouds sidecar, imported clouds, or ``SessionClouds``);
    the tissue's texture is tracked only with ``texture`` (a method reads it)."""
    source = open_source(item)
    try:
        targets = force_target(source.force_at_frames(), config.target)
        times = np.asarray(source.frame_times_ns(), dtype=np.int64)
        # seeded by the session's file name, so a session draws the same pools from any folder
        rng = np.random.default_rng(
            [config.seed, zlib.crc32(os.path.basename(source.name).encode())]
        )
        pool_size = config.pool_factor * config.n_points
        preparer: FramePreparer | None = None
        kept, features = [], []
        no_cloud = no_force = 0
        for i in range(source.n_frames):
            # the first usable frame is the rest reference even when the stride skips it
            if i % config.frame_stride and preparer is not None:
                continue
            points, colors = source.cloud(i), source.colors(i)
            if preparer is None:
                try:
                    preparer = FramePreparer(points, config, colors, texture)
                except EstimateError:
                    preparer = None
            cropped = preparer.cropped(points) if preparer is not None else None
            if i % config.frame_stride:
                continue
            if cropped is None:
                no_cloud += 1
            elif not np.isfinite(targets[i]).all():
                no_force += 1
            else:
                assert preparer is not None  # it cropped the cloud
                kept.append(i)
                features.append(preparer.features(cropped, pool_size, rng, points, colors))
        return PreparedSession.from_features(
            source.name,
            dict(source.conditions),
            features,
            np.asarray(kept, dtype=np.int64),
            times[kept],
            targets[kept],
            config,
            n_frames_total=len(range(0, source.n_frames, config.frame_stride)),
            n_no_cloud=no_cloud,
            n_no_force=no_force,
        )
    finally:
        source.close()


def prepare_sessions(
    items: Sequence[SessionLike],
    config: TrainConfig,
    progress: ProgressFn | None = None,
    texture: bool = True,
    workers: int | None = None,
) -> list[PreparedSession]:
    """Prepare several sessions (the texture tracked only with ``texture``), in order; an
    error names the session that has no usable frame. Once one session took longer than a
    worker process takes to start (:data:`WORKER_START_S`), the rest, when they are files,
    are prepared in ``workers`` processes (default: one per core)."""
    prepared: list[PreparedSession] = []

    def add(session: PreparedSession) -> None:
        if session.n_used == 0:
            raise EstimateError(
                f"session {session.name} has no usable frame ({session.n_no_cloud}"
                f" frames with too few points in the ROI, {session.n_no_force} "
                "without a force): check the ROI in [train], run `vbfe "
                "reconstruct` again or check the force column"
            )
        prepared.append(session)
        if progress is not None:
            progress("sessions", len(prepared), len(items))

    rest = list(items)
    while rest:
        clock = time.perf_counter()
        add(prepare_session(rest.pop(0), config, texture))
        n_workers = min(workers or os.cpu_count() or 1, len(rest))
        files = all(isinstance(item, (str, os.PathLike)) for item in rest)
        if n_workers >= 2 and files and time.perf_counter() - clock > WORKER_START_S:
            log.info("preparing %d sessions in %d processes", len(rest), n_workers)
            with contextlib.closing(_in_processes(rest, config, texture, n_workers)) as sessions:
                for session in sessions:
                    add(session)
            break
    return prepared


def _in_processes(
    items: list[SessionLike], config: TrainConfig, texture: bool, workers: int
) -> Generator[PreparedSession, None, None]:
    """The sessions prepared in ``workers`` spawned processes, in order."""
    pool = spawn_pool(workers)
    try:
        with stop_pool_on_signals(pool):
            yield from pool.map(prepare_session, items, repeat(config), repeat(texture))
    finally:  # on Ctrl-C or an error, drop the sessions not started yet
        pool.shutdown(wait=True, cancel_futures=True)


def skipped_counts(sessions: Sequence[PreparedSession]) -> dict[str, dict[str, int]]:
    """Per session: frames considered, used and skipped (too few ROI points, or no force)."""
    return {
        s.name: {
            "frames": s.n_frames_total,
            "used": s.n_used,
            "skipped": s.n_skipped,
            "no_cloud": s.n_no_cloud,
            "no_force": s.n_no_force,
        }
        for s in sessions
    }


class FrameBatches:
    """Frames of some sessions as torch batches, with ``n_points`` redrawn from each pool.

    ``parts`` are (session, used-frame positions) pairs. With a ``window`` (offsets back in
    frames, oldest first, e.g. ``[10, 5, 0]``) each example is the causal window of those
    frames preceded by the session's rest (first) frame: ``B × (1 + k) × n_points × C``;
    frames before the session start repeat its first frame. ``max_frames`` keeps a fixed,
    evenly spaced subsample (e.g. for validation).
    """

    def __init__(
        self,
        parts: Sequence[tuple[PreparedSession, np.ndarray]],
        n_points: int,
        window: Sequence[int] = (),
        max_frames: int | None = None,
    ) -> None:
        if not parts:
            raise EstimateError("no sessions to draw frames from")
        self.pools = np.concatenate([s.pools for s, _ in parts])
        starts = np.cumsum([0] + [s.n_used for s, _ in parts[:-1]])
        self.frames = np.concatenate(
            [start + np.asarray(p, np.int64) for start, (_, p) in zip(starts, parts, strict=False)]
        )
        self.first = np.concatenate(
            [np.full(len(p), start, np.int64) for start, (_, p) in zip(starts, parts, strict=False)]
        )
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
            return torch.from_numpy(np.ascontiguousarray(pools[..., : self.n_points, :]))
        order = np.argsort(rng.random(pools.shape[:-1]), axis=-1)[..., : self.n_points]
        return torch.from_numpy(np.take_along_axis(pools, order[..., None], axis=-2))

    def batches(
        self, batch_size: int, rng: np.random.Generator | None
    ) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """(points, targets) batches; shuffled with fresh points when ``rng`` is given."""
        order = rng.permutation(len(self)) if rng is not None else np.arange(len(self))
        for start in range(0, len(order), batch_size):
            index = order[start : start + batch_size]
            yield self.draw(index, rng), torch.from_numpy(self.targets[index])
