"""``verify_session``: read every chunk of a session and report those whose checksum fails.

Frames and samples are stored with HDF5's Fletcher-32 filter, so a changed byte in a chunk makes
its read fail instead of returning altered data; this walks every chunk of every dataset.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from vbfe.acquire.session.reader import open_session_file, read_failure_reason


@dataclass(frozen=True)
class Damage:
    """One unreadable chunk: dataset, the rows it holds and, for images, the frames."""

    dataset: str
    first_row: int
    last_row: int
    frames: tuple[int, ...]
    reason: str

    def text(self) -> str:
        """One line naming what is damaged."""
        what = (
            f"frame{'s' if len(self.frames) > 1 else ''} {', '.join(map(str, self.frames))}"
            if self.frames
            else f"rows {self.first_row}-{self.last_row}"
            if self.first_row >= 0
            else "structure (HDF5 metadata)"
        )
        return f"damaged   {self.dataset}: {what} ({self.reason})"


def _frames_of(f: h5py.File, ds: h5py.Dataset, first: int, last: int) -> tuple[int, ...]:
    """Frames stored in rows ``first … last`` of a camera dataset."""
    name = ds.name.rsplit("/", 1)[-1]
    if not ds.name.startswith("/camera/") or name.startswith(("t_", "seq")):
        return ()
    if name.endswith("_jpeg"):
        try:
            index = f[f"{ds.name}_index"][()]
        except OSError:
            return ()
        starts, ends = index[:, 0], index[:, 0] + index[:, 1]
        return tuple(int(i) for i in np.flatnonzero((starts <= last) & (ends > first)))
    if name.endswith("_jpeg_index") or name in ("left", "right"):
        return tuple(range(first, last + 1))
    return ()


def verify_session(path: str | Path) -> tuple[int, list[Damage]]:
    """Read every chunk of every dataset; returns ``(chunks read, damaged chunks)``."""
    f, _ = open_session_file(path)
    datasets: list[h5py.Dataset] = []
    damage: list[Damage] = []

    def visit(name: str) -> None:
        try:
            obj = f[name]
        except (KeyError, OSError, RuntimeError) as exc:
            damage.append(Damage(name, -1, -1, (), read_failure_reason(exc)))
            return
        if isinstance(obj, h5py.Dataset):
            datasets.append(obj)

    with f:
        try:
            f.visit(visit)
        except (KeyError, OSError, RuntimeError) as exc:  # a group's own metadata
            damage.append(Damage("/", -1, -1, (), read_failure_reason(exc)))
        chunks = 0
        for ds in datasets:
            if ds.chunks is None or ds.size == 0:
                continue
            for sel in ds.iter_chunks():
                chunks += 1
                try:
                    ds[sel]
                except OSError as exc:
                    first, last = sel[0].start, sel[0].stop - 1
                    damage.append(
                        Damage(
                            ds.name.lstrip("/"),
                            first,
                            last,
                            _frames_of(f, ds, first, last),
                            read_failure_reason(exc),
                        )
                    )
        return chunks, damage
