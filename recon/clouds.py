"""The point-cloud sidecar ``<session>.clouds.h5`` (owned by recon) and PLY export.

Layout (all per-frame arrays share the frame order of the session):

- attrs: ``format = "vbfe-clouds"``, ``format_version``, ``session_path``,
  ``session_fingerprint`` (SHA-256 of the session's start time and camera timestamps),
  ``complete``, ``verify``, ``sgbm_json``, ``software_version``
- ``calibration_yaml``: the calibration used (OpenCV YAML text)
- ``points`` (N×3 float32, ``units = "m"``, rectified left-camera frame) and ``colors`` (N×3
  uint8, ``channel_order = "RGB"``): all frames concatenated
- ``offsets`` (n_frames + 1, int64): frame ``i`` is rows ``offsets[i]:offsets[i+1]``
- ``frame_index`` (int64, session frame number), ``t_host_ns`` (int64, synchronized frame time)
- ``valid_fraction`` (float32: density, share of pixels with a point), ``disparity_px``
  (n_frames × 4 float32: min, median, max, mean of the valid disparities), ``match_counts``
  (n_frames × 4 int64: SGBM matches, kept, corrected, rejected by the De Bruijn verification;
  -1 without verification)
- since format version 3: ``verified`` (N bool, beside ``points``): the point's match agrees
  with the De Bruijn code (False where the pattern could not be read and SGBM's match was
  kept, and everywhere without verification)
- since format version 2: ``decoded_fraction`` (float32, share of left pixels with a readable
  De Bruijn code; NaN without verification), ``edge_fraction`` (float32, share of SGBM matches
  at either end of the disparity range) and the attribute ``source_kind`` (``"session"`` or
  ``"images"``; for images ``session_path`` is the first left image and the fingerprint is
  the SHA-256 of the image files)
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from vbfe.acquire.session.h5attrs import plain_attrs, text
from vbfe.common.closing import ClosedOnExit
from vbfe.common.errors import ReconError
from vbfe.common.files import atomic_path, create_hdf5, require_free_space
from vbfe.recon.deflated_rows import LEVEL, DeflatedRows

FORMAT_NAME = "vbfe-clouds"
FORMAT_VERSION = 3
# deflate (built into every HDF5, so h5dump and MATLAB read the clouds), without byte shuffle:
# on the full demo's clouds shuffle made the points 1.7x larger and their writing 2x slower;
# the chunks are compressed on threads (``deflated_rows.py``)
_DEFLATE = {"compression": "gzip", "compression_opts": LEVEL}
COMPRESS_THREADS = 2
DISPARITY_COLUMNS = ["min", "median", "max", "mean"]
COUNT_COLUMNS = ["sgbm_matches", "kept", "corrected", "rejected"]
FRAME_TABLES = {
    "frame_index": np.int64,
    "t_host_ns": np.int64,
    "valid_fraction": np.float32,
    "disparity_px": np.float32,
    "match_counts": np.int64,
    "decoded_fraction": np.float32,
    "edge_fraction": np.float32,
}


def sidecar_path(session_path: str | Path) -> Path:
    """Default sidecar next to a session: ``run.h5`` → ``run.clouds.h5``."""
    path = Path(session_path)
    return path.with_name(path.stem + ".clouds.h5")


def session_fingerprint(start_utc_ns: int, camera_times: tuple[np.ndarray, ...]) -> str:
    """SHA-256 (hex) identifying a recording by its start time and camera timestamps."""
    digest = hashlib.sha256(str(int(start_utc_ns)).encode())
    for array in camera_times:
        digest.update(np.ascontiguousarray(array, np.int64).tobytes())
    return digest.hexdigest()


def is_cloud_file(path: str | Path) -> bool:
    """Whether ``path`` is an HDF5 file in this format (complete or not)."""
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("format") == FORMAT_NAME
    except (OSError, KeyError, RuntimeError):  # not HDF5, or its attributes are damaged
        return False


FREE_MARGIN_BYTES = 4 << 20  # left free while writing: HDF5's chunk caches and tables at finish


class CloudWriter:
    """Appends frames to a sidecar; the file is marked complete only by :meth:`finish`."""

    ROWS = ("points", "colors", "verified")  # per point, every frame's in one dataset each

    def __init__(
        self, path: str | Path, attrs: Mapping[str, object], calibration_yaml: str | None
    ) -> None:
        self.path = Path(path)
        require_free_space(self.path.parent, FREE_MARGIN_BYTES, "the point clouds")
        try:
            self._file = create_hdf5(self.path)
        except OSError as exc:
            raise ReconError(f"cannot create cloud file {self.path}: {exc}") from None
        f = self._file
        f.attrs.update(
            {"format": FORMAT_NAME, "format_version": FORMAT_VERSION, "complete": False, **attrs}
        )
        if calibration_yaml is not None:  # clouds imported from elsewhere have none
            f.create_dataset("calibration_yaml", data=calibration_yaml, dtype=h5py.string_dtype())
        f.create_dataset(
            "points", (0, 3), np.float32, maxshape=(None, 3), chunks=(65536, 3), **_DEFLATE
        ).attrs["units"] = "m"
        f.create_dataset(
            "colors", (0, 3), np.uint8, maxshape=(None, 3), chunks=(65536, 3), **_DEFLATE
        ).attrs["channel_order"] = "RGB"
        f.create_dataset("verified", (0,), bool, maxshape=(None,), chunks=(65536,), **_DEFLATE)
        self._pool = ThreadPoolExecutor(COMPRESS_THREADS, thread_name_prefix="cloud-deflate")
        self._rows = {name: DeflatedRows(f[name], self._pool) for name in self.ROWS}
        self._frames: dict[str, list] = {name: [] for name in FRAME_TABLES}
        self._offsets = [0]

    def append(
        self,
        frame_index: int,
        t_host_ns: int,
        points: np.ndarray,
        colors: np.ndarray,
        stats: dict[str, object],
        verified: np.ndarray | None = None,
    ) -> None:
        """Add the next frame's cloud, its points' verified flags (default: none verified) and
        statistics (``stats``: the other per-frame tables, see :data:`FRAME_TABLES`)."""
        require_free_space(
            self.path.parent, points.nbytes + colors.nbytes + FREE_MARGIN_BYTES, "the point clouds"
        )  # stop before HDF5 meets a full disk
        start, n = self._offsets[-1], len(points)
        if verified is None:
            verified = np.zeros(n, bool)
        for name, data in zip(self.ROWS, (points, colors, verified), strict=True):
            self._rows[name].append(data)
        self._offsets.append(start + n)
        for name, value in {**stats, "frame_index": frame_index, "t_host_ns": t_host_ns}.items():
            self._frames[name].append(value)

    def finish(self) -> Path:
        """Write the per-frame tables, mark the file complete and close it."""
        require_free_space(self.path.parent, FREE_MARGIN_BYTES, "the point clouds")
        try:
            for rows in self._rows.values():
                rows.finish()
        finally:
            self._pool.shutdown(wait=True)
        f = self._file
        f.create_dataset("offsets", data=np.asarray(self._offsets, np.int64))
        columns = {"disparity_px": DISPARITY_COLUMNS, "match_counts": COUNT_COLUMNS}
        for name, dtype in FRAME_TABLES.items():
            data = np.asarray(self._frames[name], dtype)
            if name in columns:
                data = data.reshape(-1, len(columns[name]))
            ds = f.create_dataset(name, data=data)
            if name in columns:
                ds.attrs["columns"] = columns[name]
        f["t_host_ns"].attrs["units"] = "ns"
        f["disparity_px"].attrs["units"] = "px"
        f.attrs["n_frames"] = len(self._offsets) - 1
        f.attrs["complete"] = True
        f.close()
        return self.path

    def abort(self) -> None:
        """Close without marking complete (the caller removes the file). The file is first cut
        to nothing: after a write failed on a full disk, that gives HDF5 the room to write out
        its caches, where closing would otherwise fail again and crash the process later."""
        self._pool.shutdown(wait=True, cancel_futures=True)
        with contextlib.suppress(OSError, ValueError):
            os.ftruncate(self._file.id.get_vfd_handle(), 0)
        self._file.close()


class CloudReader(ClosedOnExit):
    """Read a sidecar written by :func:`vbfe.recon.reconstruct_session` (context manager)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise ReconError(
                f"cloud file {self.path} does not exist; create it with "
                f"'vbfe reconstruct SESSION.h5'"
            )
        try:
            self._file = h5py.File(self.path, "r")
        except OSError as exc:
            raise ReconError(f"{self.path} is not a readable HDF5 file: {exc}") from None
        attrs = self._file.attrs
        if attrs.get("format") != FORMAT_NAME or not attrs.get("complete", False):
            self._file.close()
            raise ReconError(
                f"{self.path} is not a complete vbfe cloud file (interrupted "
                f"reconstruction?); run 'vbfe reconstruct' again"
            )
        try:
            self._offsets = self._file["offsets"][()]
            n_points = len(self._file["points"]), len(self._file["colors"])
        except (KeyError, OSError) as exc:
            self._file.close()
            raise ReconError(
                f"{self.path} is damaged ({' '.join(str(exc).split())}); run "
                "'vbfe reconstruct' again"
            ) from None
        if (
            len(self._offsets) < 1
            or self._offsets[0] != 0
            or np.any(np.diff(self._offsets) < 0)
            or not self._offsets[-1] == n_points[0] == n_points[1]
        ):
            self._file.close()
            raise ReconError(
                f"{self.path} is damaged (its frame offsets do not match its "
                "points); run 'vbfe reconstruct' again"
            )

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    @property
    def n_frames(self) -> int:
        """Number of frames (same as the session's)."""
        return len(self._offsets) - 1

    @property
    def session_path(self) -> Path:
        """The session these clouds were computed from."""
        return Path(self._file.attrs["session_path"])

    @property
    def session_fingerprint(self) -> str:
        """Fingerprint of that session (compare with :func:`session_fingerprint`)."""
        return str(self._file.attrs["session_fingerprint"])

    @property
    def attrs(self) -> dict[str, Any]:
        """Root attributes (format, verify, SGBM settings, software version, …)."""
        out = plain_attrs(self._file.attrs)
        out["sgbm"] = json.loads(str(out.get("sgbm_json", "{}")))
        return out

    def cloud(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``i``: points (N×3 float32, m) and colours (N×3 uint8, RGB)."""
        if not -self.n_frames <= i < self.n_frames:
            raise IndexError(f"frame {i} out of range: {self.path} has {self.n_frames} frames")
        i %= self.n_frames
        start, stop = int(self._offsets[i]), int(self._offsets[i + 1])
        try:
            return self._file["points"][start:stop], self._file["colors"][start:stop]
        except OSError:
            raise ReconError(
                f"{self.path}: frame {i} cannot be read (the stored bytes changed "
                "after writing); run 'vbfe reconstruct' again"
            ) from None

    def verified(self, i: int) -> np.ndarray:
        """Frame ``i``'s verified flag per point (N bool). Files before version 3 kept only
        verified points when verification ran, so their points read as all verified then."""
        points, _ = self.cloud(i)
        if "verified" not in self._file:
            return np.full(len(points), bool(self._file.attrs.get("verify", False)))
        i %= self.n_frames
        return self._file["verified"][int(self._offsets[i]) : int(self._offsets[i + 1])]

    def frame_table(self, name: str) -> np.ndarray:
        """A per-frame array named in :data:`FRAME_TABLES` (quality tables missing from a
        version-1 file read as NaN)."""
        if name not in FRAME_TABLES:
            raise ReconError(
                f"{self.path} has no per-frame table {name!r}; known: {sorted(FRAME_TABLES)}"
            )
        if name not in self._file:
            return np.full(self.n_frames, np.nan, np.float32)
        return self._file[name][()]

    def calibration_yaml(self) -> str:
        """The calibration the clouds were computed with."""
        return text(self._file["calibration_yaml"][()])


def write_ply(path: str | Path, points: np.ndarray, colours: np.ndarray | None = None) -> Path:
    """Write a binary little-endian PLY (float x, y, z in metres; uchar red, green, blue)."""
    path = Path(path)
    points = np.asarray(points, np.float32).reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colours is not None:
        colours = np.asarray(colours, np.uint8).reshape(-1, 3)
        if len(colours) != len(points):
            raise ReconError(f"{len(points)} points but {len(colours)} colours for {path}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vertices = np.empty(len(points), dtype=fields)
    for k, axis in enumerate("xyz"):
        vertices[axis] = points[:, k]
    if colours is not None:
        for k, channel in enumerate(("red", "green", "blue")):
            vertices[channel] = colours[:, k]
    types = {"<f4": "float", "u1": "uchar"}
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment units m",
        f"element vertex {len(points)}",
        *(f"property {types[t]} {name}" for name, t in fields),
        "end_header",
    ]
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            fh.write(("\n".join(header) + "\n").encode("ascii"))
            fh.write(vertices.tobytes())
    except OSError as exc:
        raise ReconError(f"cannot write PLY file {path}: {exc}") from None
    return path


def export_ply(
    clouds_path: str | Path, out_dir: str | Path, frames: list[int] | None = None
) -> list[Path]:
    """Write ``frame_000123.ply`` files for the given (default: all) frames of a sidecar."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with CloudReader(clouds_path) as reader:
        indices = reader.frame_table("frame_index")
        chosen = range(reader.n_frames) if frames is None else frames
        return [
            write_ply(out_dir / f"frame_{int(indices[i]):06d}.ply", *reader.cloud(i))
            for i in chosen
        ]
