"""Where training data comes from: a recorded session with its clouds sidecar, a clouds file
written by ``vbfe import`` (``*.clouds.h5`` with a ``labels`` group), or clouds in memory.

All kinds answer the same questions (name, conditions, frame times, force at each frame, the
point cloud of frame ``i`` and its points' colours, ``None`` when it has none), so dataset
building never cares which one it reads.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import h5py
import numpy as np

from vbfe.acquire import SessionReader
from vbfe.common.errors import EstimateError, VbfeError
from vbfe.recon import CloudReader, sidecar_path

CLOUDS_SUFFIX = ".clouds.h5"
LABELS_GROUP = "labels"  # written by ``vbfe import``: force_n (frames × 3, N), conditions_json


class CloudSource(Protocol):
    """One session's frames as point clouds, labelled with the trocar force."""

    name: str
    conditions: dict[str, Any]

    @property
    def n_frames(self) -> int: ...

    def frame_times_ns(self) -> np.ndarray: ...
    def force_at_frames(self) -> np.ndarray: ...
    def cloud(self, i: int) -> np.ndarray: ...
    def colors(self, i: int) -> np.ndarray | None: ...
    def close(self) -> None: ...


@dataclass
class SessionClouds:
    """A session held in memory: ``clouds[i]`` is an N_i×3 array in metres (may be empty/NaN),
    ``point_colors[i]`` its points' colours (N_i×3 RGB; ``None``: no colours)."""

    name: str
    clouds: list[np.ndarray]
    forces_n: np.ndarray  # n_frames × 3, newtons, at each frame's time
    times_ns: np.ndarray  # n_frames, int64
    conditions: dict[str, Any] = field(default_factory=dict)
    point_colors: list[np.ndarray] | None = None

    @property
    def n_frames(self) -> int:
        return len(self.clouds)

    def frame_times_ns(self) -> np.ndarray:
        return np.asarray(self.times_ns, dtype=np.int64)

    def force_at_frames(self) -> np.ndarray:
        return np.asarray(self.forces_n, dtype=np.float64)

    def cloud(self, i: int) -> np.ndarray:
        return np.asarray(self.clouds[i], dtype=np.float64)

    def colors(self, i: int) -> np.ndarray | None:
        return None if self.point_colors is None else np.asarray(self.point_colors[i])

    def close(self) -> None:
        pass


class _LastFrame:
    """A clouds file's frames, the newest one read kept: its points and colours are asked for
    one after the other."""

    def __init__(self, reader: CloudReader) -> None:
        self.reader = reader
        self._index = -1
        self._frame: tuple[np.ndarray, np.ndarray] = (np.empty((0, 3)), np.empty((0, 3)))

    def __call__(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        if i != self._index:
            self._frame, self._index = self.reader.cloud(i), i
        return self._frame


def clouds_path_for(session_path: str | Path) -> Path:
    """The ``<session>.clouds.h5`` sidecar that ``vbfe reconstruct`` wrote next to a session."""
    clouds = sidecar_path(session_path)
    if not clouds.exists():
        raise EstimateError(
            f"session {session_path} has no point clouds ({clouds.name} not "
            f"found): run `vbfe reconstruct {session_path}` first"
        )
    return clouds


class RecordedSession:
    """A recorded session file read through ``acquire.SessionReader`` and ``recon.CloudReader``."""

    def __init__(self, session_path: str | Path) -> None:
        self.path = Path(session_path)
        if not self.path.exists():
            raise EstimateError(f"session {self.path} does not exist")
        clouds = clouds_path_for(self.path)
        try:
            self._session = SessionReader(self.path)
            self._clouds = CloudReader(clouds)
        except VbfeError as exc:
            raise EstimateError(f"cannot read {self.path} / {clouds.name}: {exc}") from exc
        self._frame = _LastFrame(self._clouds)
        if self._clouds.n_frames != self._session.n_frames:
            self.close()
            raise EstimateError(
                f"{clouds} has {self._clouds.n_frames} clouds but {self.path} has "
                f"{self._session.n_frames} frames: run `vbfe reconstruct` again"
            )
        self.name = str(self.path)
        self.n_frames = int(self._session.n_frames)
        self.conditions = dict(self._session.metadata.get("conditions") or {})

    def frame_times_ns(self) -> np.ndarray:
        return np.asarray(self._session.frame_times_ns(), dtype=np.int64)

    def force_at_frames(self) -> np.ndarray:
        return np.asarray(self._session.force_at_frames(), dtype=np.float64)

    def cloud(self, i: int) -> np.ndarray:
        return np.asarray(self._frame(i)[0], dtype=np.float64)

    def colors(self, i: int) -> np.ndarray | None:
        return self._frame(i)[1]

    def close(self) -> None:
        for reader in (getattr(self, "_clouds", None), getattr(self, "_session", None)):
            if reader is not None and hasattr(reader, "close"):
                reader.close()


class ImportedClouds:
    """A clouds file written by ``vbfe import``: recon's cloud format plus force labels."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            with h5py.File(self.path, "r") as f:
                labels = f.get(LABELS_GROUP)
                if labels is None or "force_n" not in labels:
                    raise EstimateError(
                        f"{self.path} holds point clouds but no forces; give the session .h5 "
                        "it was reconstructed from, or create the file with `vbfe import`"
                    )
                self._forces = np.asarray(labels["force_n"][()], dtype=np.float64)
                self.conditions = dict(json.loads(labels.attrs.get("conditions_json", "{}")))
        except OSError as exc:
            raise EstimateError(f"{self.path} is not a readable clouds file: {exc}") from None
        try:
            self._clouds = CloudReader(self.path)
        except VbfeError as exc:
            raise EstimateError(f"cannot read {self.path}: {exc}") from exc
        self._frame = _LastFrame(self._clouds)
        self.name = str(self.path)
        self.n_frames = self._clouds.n_frames
        if len(self._forces) != self.n_frames:
            self.close()
            raise EstimateError(
                f"{self.path} has {len(self._forces)} force rows for "
                f"{self.n_frames} clouds: import it again"
            )

    def frame_times_ns(self) -> np.ndarray:
        return np.asarray(self._clouds.frame_table("t_host_ns"), dtype=np.int64)

    def force_at_frames(self) -> np.ndarray:
        return self._forces

    def cloud(self, i: int) -> np.ndarray:
        return np.asarray(self._frame(i)[0], dtype=np.float64)

    def colors(self, i: int) -> np.ndarray | None:
        return self._frame(i)[1]

    def close(self) -> None:
        self._clouds.close()


SessionLike = str | Path | SessionClouds


def open_source(item: SessionLike) -> CloudSource:
    """A session path (with its clouds sidecar), an imported ``*.clouds.h5`` file, or an
    in-memory ``SessionClouds`` as a source."""
    if isinstance(item, SessionClouds):
        return item
    if str(item).endswith(CLOUDS_SUFFIX):
        if not Path(item).is_file():
            raise EstimateError(f"clouds file {item} does not exist")
        return ImportedClouds(item)
    return RecordedSession(item)


def condition_label(conditions: dict[str, Any]) -> str:
    """``"80 N/m @ 0.005 m/s"``-style label of a session's stiffness × pull speed (or the
    ``label`` given at import)."""
    if conditions.get("label"):
        return str(conditions["label"])
    parts = [
        f"{conditions[key]:g} {unit}"
        for key, unit in (("stiffness_n_per_m", "N/m"), ("pull_speed_m_per_s", "m/s"))
        if key in conditions
    ]
    return " @ ".join(parts) if parts else "unknown"
