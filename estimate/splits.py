"""Which frames train, validate and test a model: whole sessions, or frame ranges in time.

A split by session (``split_by_session``) holds out whole sessions. A time split keeps
contiguous frame ranges inside each session, always stated in the session's own frame numbers
(``[start, stop)``): ``split_by_time`` puts training first, then validation, then test;
``split_by_ranges`` takes the ranges a user states (``--train 0:565 --val 595:700``);
``split_folds`` cuts each session into K contiguous blocks for blocked cross-validation, fold
k testing on block k and validating on its neighbour. ``gap_frames`` frames of a lower part
(train < val < test) next to a higher one are left out of every part, so no frame used for
fitting lies within the gap of a held-out one. A split never deals frames one by one.
"""

from __future__ import annotations

import os
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from vbfe.common.errors import EstimateError

PARTS = ("train", "val", "test")


class FramedSession(Protocol):
    """What a split reads of a prepared session."""

    name: str
    frame_index: np.ndarray  # the session's frame number of every used frame

    @property
    def condition(self) -> str: ...

    @property
    def protocol(self) -> str: ...

    @property
    def n_used(self) -> int: ...


def _session_key(name: str) -> str:
    """A session's identity: its resolved path when it names a file, else the name."""
    return os.path.realpath(name) if os.path.exists(name) else name


def _ranges_text(ranges: Sequence[Sequence[int]]) -> str:
    return ",".join(f"{a}:{b}" for a, b in ranges) or "-"


@dataclass
class SessionSplit:
    """Which frames are in each part: whole sessions (``kind="session"``) or, for
    ``kind="time"``, frame ranges ``[start, stop)`` (the session's frame numbers) per part and
    session. ``train``/``val``/``test`` name the sessions that have frames in each part."""

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

    def positions(self, part: str, session: FramedSession) -> np.ndarray:
        """Used-frame positions of ``session`` that belong to ``part`` (may be empty)."""
        found = self._find(session.name, getattr(self, part))
        if found is None:
            return np.zeros(0, dtype=np.int64)
        if self.kind == "time":
            frames = np.asarray(session.frame_index)
            inside = np.zeros(len(frames), dtype=bool)
            for a, b in self.blocks[part][found]:
                inside |= (frames >= a) & (frames < b)
            return np.flatnonzero(inside)
        return np.arange(session.n_used)

    def frames(self, part: str, sessions: Sequence[Any]) -> list[tuple[Any, np.ndarray]]:
        """(session, positions) of every session with frames in ``part``."""
        picked = [(s, self.positions(part, s)) for s in sessions]
        return [(s, p) for s, p in picked if len(p)]

    def describe(self) -> str:
        """One line: the kind of split and its parts (time: frame ranges of every session)."""
        if self.kind == "session":
            return (
                f"split by session: {len(self.train)} train, {len(self.val)} validation, "
                f"{len(self.test)} test session(s)"
            )
        names = list(dict.fromkeys(n for part in PARTS for n in self.blocks.get(part, {})))
        per_session = []
        for name in names:
            parts = " ".join(
                f"{part} {_ranges_text(self.blocks.get(part, {}).get(name, []))}" for part in PARTS
            )
            per_session.append(f"{os.path.basename(name)} {parts}")
        return (
            f"split by frame ranges [start:stop) in time, gap {self.gap_frames} frames: "
            + "; ".join(per_session)
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "train": list(self.train),
            "val": list(self.val),
            "test": list(self.test),
            "kind": self.kind,
            "gap_frames": self.gap_frames,
            "blocks": self.blocks,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SessionSplit:
        return cls(
            train=list(d.get("train", [])),
            val=list(d.get("val", [])),
            test=list(d.get("test", [])),
            kind=d.get("kind", "session"),
            gap_frames=int(d.get("gap_frames", 0)),
            blocks=d.get("blocks", {}),
        )


def autocorrelation_frames(values: np.ndarray) -> int:
    """The force's autocorrelation time: the first lag (frames) at which the autocorrelation
    of ``values`` (frames × outputs; the mean of the outputs') falls below 1/e (the series'
    length when it never does). Frames closer than this to a held-out one nearly copy it."""
    series = np.asarray(values, np.float64).reshape(len(values), -1)
    centred = series - series.mean(axis=0)
    power = (centred**2).sum()
    if len(series) < 2 or power <= 0:
        return 0
    acf = np.array(
        [
            (centred[lag:] * centred[: len(series) - lag]).sum() / power
            for lag in range(1, len(series))
        ]
    )
    below = np.flatnonzero(acf < np.exp(-1))
    return int(below[0]) + 1 if len(below) else len(series)


def split_by_session(
    sessions: Sequence[FramedSession], val_fraction: float, test_fraction: float, seed: int
) -> SessionSplit:
    """Split sessions (not frames) into train/val/test, stratified by protocol and condition.

    Each protocol (pull-and-hold, freehand, …) is split apart and gives validation and test
    its share of sessions, so the held-out frames that select the model and calibrate its
    intervals include every protocol with enough sessions. Within a protocol, each condition's
    sessions are shuffled and dealt round-robin so that every part gets its share of every
    condition when there are enough repeats; at least one session of each protocol always
    stays in training.
    """
    rng = np.random.default_rng(seed)
    protocols: dict[str, list[FramedSession]] = defaultdict(list)
    for s in sessions:
        protocols[s.protocol].append(s)
    split = SessionSplit(train=[])
    for protocol in sorted(protocols):
        part = _deal_sessions(protocols[protocol], val_fraction, test_fraction, rng)
        split.train += part.train
        split.val += part.val
        split.test += part.test
    return split


def _deal_sessions(
    sessions: Sequence[FramedSession],
    val_fraction: float,
    test_fraction: float,
    rng: np.random.Generator,
) -> SessionSplit:
    """The split of one protocol's sessions, stratified by condition."""
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
    val = reversed_order[n_test : n_test + n_val]
    train = [name for name in ordered if name not in set(test) | set(val)]
    return SessionSplit(train=train, val=val, test=test)


def _ranges(frames: np.ndarray, mask: np.ndarray) -> list[list[int]]:
    """``[start, stop)`` frame-number ranges of the runs of True in ``mask`` over used frames."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return [
        [int(frames[a]), int(frames[b - 1]) + 1]
        for a, b in zip(edges[::2], edges[1::2], strict=False)
    ]


def _from_labels(
    sessions: Sequence[FramedSession], labels: Sequence[np.ndarray], gap_frames: int
) -> SessionSplit:
    """A time split from a part label per used frame (0 train, 1 val, 2 test, -1 none) of
    every session, with the gap cut out of the lower part at every boundary."""
    blocks: dict[str, dict[str, list[list[int]]]] = {part: {} for part in PARTS}
    for s, label in zip(sessions, labels, strict=False):
        frames = np.asarray(s.frame_index)
        label = label.copy()
        for higher in (1, 2):
            held = np.sort(frames[label == higher])
            if not len(held) or not gap_frames:
                continue
            at = np.searchsorted(held, frames)
            distance = np.minimum(
                np.abs(frames - held[np.clip(at, 0, len(held) - 1)]),
                np.abs(frames - held[np.clip(at - 1, 0, len(held) - 1)]),
            )
            label[(label >= 0) & (label < higher) & (distance <= gap_frames)] = -1
        for k, part in enumerate(PARTS):
            ranges = _ranges(frames, label == k)
            if ranges:
                blocks[part][s.name] = ranges
    return SessionSplit(
        train=list(blocks["train"]),
        val=list(blocks["val"]),
        test=list(blocks["test"]),
        kind="time",
        gap_frames=gap_frames,
        blocks=blocks,
    )


def split_by_time(
    sessions: Sequence[FramedSession], val_fraction: float, test_fraction: float, gap_frames: int
) -> SessionSplit:
    """Each session in time order: the first ``1 − val − test`` of its used frames train,
    then validation, then test (contiguous ranges, gaps between)."""
    labels = []
    for s in sessions:
        position = np.arange(s.n_used) / max(s.n_used, 1)
        labels.append(
            np.where(
                position < 1 - val_fraction - test_fraction,
                0,
                np.where(position < 1 - test_fraction, 1, 2),
            )
        )
    return _from_labels(sessions, labels, gap_frames)


def parse_range(text: str, what: str) -> list[int]:
    """``"595:700"`` → ``[595, 700]`` (frame numbers, stop excluded)."""
    try:
        start, stop = (int(v) for v in str(text).split(":"))
    except ValueError:
        raise EstimateError(f"{what} {text!r}: give a frame range START:STOP, e.g. 0:565") from None
    if not 0 <= start < stop:
        raise EstimateError(f"{what} {text!r}: needs 0 <= START < STOP")
    return [start, stop]


def split_by_ranges(
    sessions: Sequence[FramedSession], ranges: dict[str, list[int]]
) -> SessionSplit:
    """The frame ranges a user stated (``part → [start, stop)``), the same in every session."""
    stated = sorted((r, part) for part, r in ranges.items() if r)
    for (a, part_a), (b, part_b) in zip(stated, stated[1:], strict=False):
        if b[0] < a[1]:
            raise EstimateError(
                f"frame ranges overlap: {part_a} {a[0]}:{a[1]} and {part_b} "
                f"{b[0]}:{b[1]}; give disjoint ranges"
            )
    labels = []
    for s in sessions:
        frames = np.asarray(s.frame_index)
        label = np.full(len(frames), -1)
        for k, part in enumerate(PARTS):
            if ranges.get(part):
                first, end = ranges[part]
                label[(frames >= first) & (frames < end)] = k
        if not (label == 0).any():
            raise EstimateError(
                f"session {s.name} has no usable frame in the training range "
                f"{ranges['train'][0]}:{ranges['train'][1]} (frames "
                f"{frames.min()}..{frames.max()} are usable)"
            )
        labels.append(label)
    return _from_labels(sessions, labels, 0)


def split_folds(
    sessions: Sequence[FramedSession], folds: int, gap_frames: int
) -> list[SessionSplit]:
    """Blocked K-fold cross-validation: each session's used frames in ``folds`` contiguous
    blocks; fold k tests on block k, validates on block k − 1 (block 1 for the first fold)
    and trains on the rest, with the gap cut at every boundary."""
    if folds < 3:
        raise EstimateError(f"--folds {folds}: blocked cross-validation needs at least 3 folds")
    splits = []
    for k in range(folds):
        labels = []
        for s in sessions:
            if s.n_used < folds:
                raise EstimateError(
                    f"session {s.name} has {s.n_used} usable frames, fewer than --folds {folds}"
                )
            block = np.arange(s.n_used) * folds // s.n_used
            label = np.zeros(s.n_used, dtype=np.int64)
            label[block == (k - 1 if k else 1)] = 1
            label[block == k] = 2
            labels.append(label)
        splits.append(_from_labels(sessions, labels, gap_frames))
    return splits
