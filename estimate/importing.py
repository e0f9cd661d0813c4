"""``vbfe import``: external recordings → a clouds file with forces that train/evaluate read.

Frames come from a folder of point clouds (``*.ply`` or ``*.npy``, N×3 metres) or of 16-bit
depth PNGs back-projected with pinhole intrinsics (``fx fy cx cy`` in pixels of the camera's
image, of which the PNGs may be crops), a depth scale (metres per depth unit; 0 and 65535 = no
depth) and an optional pixel region of interest; files are taken in natural order (``data2``
before ``data10``) and depths outside a range are dropped. Forces come from a text table
(:mod:`vbfe.estimate.tables`): a time column (resampled linearly at the frame times, NaN
outside the force record), a frame-index column (0 = first frame file), or one row per frame.
The clouds are written with recon's ``CloudWriter`` (the format of ``vbfe reconstruct``'s
sidecars); the forces at the frames and the conditions go in a ``labels`` group of the same
file (see docs/how-to/import.md).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import h5py
import numpy as np

from vbfe.acquire.resample import resample_at
from vbfe.common.errors import EstimateError
from vbfe.common.files import commit, partial_path
from vbfe.common.version import __version__
from vbfe.estimate.sources import CLOUDS_SUFFIX, LABELS_GROUP
from vbfe.estimate.tables import read_table
from vbfe.recon.clouds import CloudWriter

IMPORT_SOURCE = "import"  # the clouds file's source_kind
FORCE_UNITS_N = {
    "N": 1.0,
    "mN": 1e-3,
    "kN": 1e3,
    "gf": 9.80665e-3,
    "kgf": 9.80665,
    "lbf": 4.4482216152605,
}
TIME_UNITS_NS = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}
PLY_TYPES = {
    "char": "i1",
    "uchar": "u1",
    "int8": "i1",
    "uint8": "u1",
    "short": "i2",
    "ushort": "u2",
    "int16": "i2",
    "uint16": "u2",
    "int": "i4",
    "uint": "u4",
    "int32": "i4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
INVALID_DEPTH = (0, 65535)  # no return / saturated 16-bit depth


@dataclass(frozen=True)
class DepthCamera:
    """Pinhole intrinsics (pixels of the camera's image), depth scale (m per unit), optional
    ROI ``x0 y0 x1 y1`` (pixels of the files) and the files' ``crop_origin`` in the camera's
    image (their top-left pixel; None: the files are the whole image)."""

    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale_m: float
    roi: tuple[int, int, int, int] | None = None
    pixel_step: int = 1
    crop_origin: tuple[int, int] | None = None

    def check(self, width: int, height: int) -> None:
        """Refuse intrinsics that cannot describe a ``width × height`` depth image."""
        if self.fx <= 0 or self.fy <= 0 or self.depth_scale_m <= 0 or self.pixel_step < 1:
            raise EstimateError("fx, fy and --depth-scale must be positive and --pixel-step >= 1")
        if not all(map(math.isfinite, (self.fx, self.fy, self.cx, self.cy, self.depth_scale_m))):
            raise EstimateError("--fx --fy --cx --cy and --depth-scale must be finite numbers")
        if self.crop_origin is None and not (0 <= self.cx < width and 0 <= self.cy < height):
            raise EstimateError(
                f"principal point ({self.cx}, {self.cy}) is outside the "
                f"{width}x{height} depth image; check --cx/--cy, or if the "
                "images are crops of the camera's image give --crop-origin X Y "
                "(the crop's top-left pixel in it)"
            )
        if self.crop_origin is not None and min(*self.crop_origin, self.cx, self.cy) < 0:
            raise EstimateError(
                f"--crop-origin {self.crop_origin[0]} {self.crop_origin[1]} and "
                f"the principal point ({self.cx}, {self.cy}) are pixels of the "
                "camera's image: they cannot be negative"
            )
        if self.roi is not None:
            x0, y0, x1, y1 = self.roi
            if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
                raise EstimateError(
                    f"--roi {x0} {y0} {x1} {y1} is not inside the "
                    f"{width}x{height} depth image (x0 y0 x1 y1, x1 > x0)"
                )

    def points(self, depth: np.ndarray) -> np.ndarray:
        """Back-projected points (N×3, metres, camera frame) of the valid ROI pixels."""
        x0, y0, x1, y1 = self.roi or (0, 0, depth.shape[1], depth.shape[0])
        v, u = np.mgrid[y0 : y1 : self.pixel_step, x0 : x1 : self.pixel_step]
        raw = depth[v, u]
        valid = ~np.isin(raw, INVALID_DEPTH)
        z = raw[valid].astype(np.float64) * self.depth_scale_m
        du, dv = self.crop_origin or (0, 0)
        u, v = u[valid] + du, v[valid] + dv
        return np.column_stack([(u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z])


def natural_key(path: Path) -> tuple[list[str | int], str]:
    """Sort key reading digit runs as numbers: ``data2`` before ``data10``."""
    parts = re.split(r"(\d+)", path.name)
    return [int(p) if i % 2 else p for i, p in enumerate(parts)], path.name


@contextmanager
def _quiet_opencv() -> Iterator[None]:
    """OpenCV's own warnings off (a broken PNG is reported once, by us)."""
    logging = cv2.utils.logging
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        logging.setLogLevel(level)


def frame_files(folder: str | Path, patterns: Sequence[str]) -> list[Path]:
    """The frame files of ``folder`` matching ``patterns``, in natural order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise EstimateError(f"{folder} is not a folder of frames")
    files = sorted({p for pattern in patterns for p in folder.glob(pattern)}, key=natural_key)
    if not files:
        raise EstimateError(f"{folder} holds no {' or '.join(patterns)} files")
    return files


def read_ply(path: str | Path) -> np.ndarray:
    """Vertex x, y, z (N×3 float64) of an ASCII or binary PLY file."""
    path = Path(path)
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise EstimateError(f"{path} is not a PLY file (no ply/end_header header)")
    body_start = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", "replace").splitlines()
    fmt, count, fields, in_vertex = "", 0, [], False
    for line in header:
        words = line.split()
        if words[:1] == ["format"]:
            fmt = words[1]
        elif words[:1] == ["element"]:
            in_vertex = words[1] == "vertex"
            count = int(words[2]) if in_vertex else count
        elif words[:1] == ["property"] and in_vertex:
            if words[1] == "list" or words[1] not in PLY_TYPES:
                raise EstimateError(
                    f"{path}: vertex property {' '.join(words[1:])} is not "
                    "supported; give x, y, z as scalar properties"
                )
            fields.append((words[2], PLY_TYPES[words[1]]))
    names = [name for name, _ in fields]
    if not {"x", "y", "z"} <= set(names):
        raise EstimateError(f"{path}: vertices need x, y and z properties, found {names}")
    if fmt == "ascii":
        rows = data[body_start:].decode("ascii", "replace").split("\n")[:count]
        try:
            table = np.array([r.split()[: len(fields)] for r in rows], dtype=np.float64)
        except ValueError:
            raise EstimateError(
                f"{path}: the ASCII vertex rows are not {len(fields)} numbers "
                f"each ({count} vertices declared)"
            ) from None
        return table.reshape(-1, len(fields))[:, [names.index(a) for a in "xyz"]]
    order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
    if order is None:
        raise EstimateError(f"{path}: unknown PLY format {fmt!r}")
    dtype = np.dtype([(name, order + t) for name, t in fields])
    if len(data) - body_start < count * dtype.itemsize:
        raise EstimateError(
            f"{path}: the file ends before its {count} declared vertices (truncated)"
        )
    vertices = np.frombuffer(data, dtype=dtype, count=count, offset=body_start)
    return np.column_stack([vertices[a].astype(np.float64) for a in "xyz"])


def read_cloud(path: Path) -> np.ndarray:
    """One point-cloud frame (PLY, or NPY of shape N×3) in metres."""
    if path.suffix.lower() == ".ply":
        return read_ply(path)
    try:
        points = np.load(path, allow_pickle=False)
    except (ValueError, EOFError, OSError):
        raise EstimateError(f"{path} is not a readable .npy array (damaged or not NumPy)") from None
    if points.ndim != 2 or points.shape[1] < 3 or points.dtype.kind not in "fiu":
        raise EstimateError(
            f"{path} holds a {points.dtype} array of shape {points.shape}; need N×3 numbers"
        )
    return np.asarray(points[:, :3], dtype=np.float64)


def read_depth(path: Path) -> np.ndarray:
    """One 16-bit single-channel depth PNG."""
    with _quiet_opencv():
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if depth is None or depth.dtype != np.uint16 or depth.ndim != 2:
        kind = "unreadable" if depth is None else f"{depth.dtype} with shape {depth.shape}"
        raise EstimateError(f"{path} is {kind}; depth frames must be 16-bit single-channel PNGs")
    return depth


def _increasing(times: np.ndarray, what: str, path: Path) -> None:
    """Refuse missing (NaN) or decreasing times (counted from 1, header not counted)."""
    bad = np.flatnonzero(~np.isfinite(times))
    if len(bad):
        raise EstimateError(
            f"{path}: {what} {bad[0] + 1} of {len(times)} is not a number (NaN "
            "or empty); every row needs its time"
        )
    back = np.flatnonzero(np.diff(times) < 0)
    if len(back):
        raise EstimateError(
            f"{path}: {what}s are not in order ({what} {back[0] + 2} is earlier "
            f"than {what} {back[0] + 1}); sort the file by time"
        )


@dataclass(frozen=True)
class ForceTable:
    """How to read forces from a text table (:func:`~vbfe.estimate.tables.read_table`): force
    columns (names or numbers), their unit and a scale, and a time or frame key (neither: row i
    is frame i)."""

    path: Path
    force_columns: tuple[str, ...]
    force_unit: str = "N"
    time_column: str | None = None
    time_unit: str = "s"
    frame_column: str | None = None
    axis: str = "z"  # where a single force column goes
    scale: float = 1.0  # multiplies the forces (e.g. sensor counts → the unit)

    def forces_at(self, frame_times_ns: np.ndarray) -> np.ndarray:
        """Force (frames × 3, newtons) at each frame."""
        if len(self.force_columns) not in (1, 3):
            raise EstimateError("--force-columns takes one column or three (x,y,z)")
        if self.time_column is not None and self.frame_column is not None:
            raise EstimateError("give at most one of --time-column and --frame-column")
        if self.force_unit not in FORCE_UNITS_N or self.time_unit not in TIME_UNITS_NS:
            raise EstimateError(
                f"units: force one of {sorted(FORCE_UNITS_N)}, time one of {sorted(TIME_UNITS_NS)}"
            )
        if not math.isfinite(self.scale) or self.scale == 0:
            raise EstimateError(f"--force-scale must be a non-zero number, not {self.scale}")
        key = self.time_column or self.frame_column
        table = read_table(self.path, [*([key] if key else []), *self.force_columns])
        values = np.column_stack([table[c] for c in self.force_columns])
        values = values * (FORCE_UNITS_N[self.force_unit] * self.scale)
        if len(self.force_columns) == 1:
            axis = "xyz".index(self.axis)
            values = np.insert(np.zeros((len(values), 2)), axis, values[:, 0], axis=1)
        n = len(frame_times_ns)
        out = np.full((n, 3), np.nan)
        if key is None:
            if len(values) != n:
                raise EstimateError(
                    f"{self.path} has {len(values)} rows for {n} frames; one row "
                    "per frame is read when neither --time-column nor "
                    "--frame-column is given"
                )
            return values
        if self.frame_column is not None:
            index = table[key]
            inside = (index >= 0) & (index < n) & (index == np.round(index))
            out[index[inside].astype(int)] = values[inside]
            return out
        t_ns = table[key] * TIME_UNITS_NS[self.time_unit]
        _increasing(t_ns, "force time", self.path)
        known = np.isfinite(values).all(axis=1)  # samples without a force are left out
        if known.sum() < 2:
            raise EstimateError(f"{self.path} needs at least two force samples to resample")
        return resample_at(frame_times_ns, np.round(t_ns[known]).astype(np.int64), values[known])


def frame_times(
    n_frames: int, fps: float | None, times_csv: Path | None, column: str | None, time_unit: str
) -> np.ndarray:
    """Frame times (ns): ``i / fps``, or a column of a table (one row per frame file)."""
    if (fps is None) == (times_csv is None):
        raise EstimateError("give exactly one of --fps and --frame-times")
    if fps is not None:
        if not fps > 0 or not math.isfinite(fps):
            raise EstimateError(f"--fps must be a positive number, not {fps}")
        return np.round(np.arange(n_frames) * 1e9 / fps).astype(np.int64)
    if column is None:
        raise EstimateError("--frame-times needs --frame-time-column (the column of frame times)")
    assert times_csv is not None  # exactly one of fps and times_csv is given
    times = read_table(times_csv, [column])[column] * TIME_UNITS_NS[time_unit]
    if len(times) != n_frames:
        raise EstimateError(f"{times_csv} has {len(times)} frame times for {n_frames} frames")
    _increasing(times, "frame time", Path(times_csv))
    if np.any(np.diff(times) == 0):
        raise EstimateError(
            f"{times_csv}: two frames have the same time; frame times must increase"
        )
    return np.round(times).astype(np.int64)


def check_out(out: str | Path, overwrite: bool) -> Path:
    """The output path: named ``*.clouds.h5``, not an existing file unless ``overwrite``."""
    out = Path(out)
    if not out.name.endswith(CLOUDS_SUFFIX):
        raise EstimateError(f"--out {out.name}: name the imported file *{CLOUDS_SUFFIX}")
    if out.exists() and not overwrite:
        raise EstimateError(f"{out} exists; give --overwrite to replace it or another --out")
    return out


def write_clouds(
    out: str | Path,
    clouds: Iterable[np.ndarray],
    times_ns: np.ndarray,
    forces_n: np.ndarray,
    conditions: dict,
    source: dict,
) -> Path:
    """Write the clouds with recon's ``CloudWriter``, then the forces and conditions (under a
    temporary name, renamed when complete: a failed import leaves nothing)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = partial_path(out)
    attrs = {
        "source_kind": IMPORT_SOURCE,
        "session_path": str(source.get("folder", "")),
        "software_version": __version__,
        "source_json": json.dumps(source),
    }
    writer = CloudWriter(tmp, attrs, calibration_yaml=None)  # no stereo calibration made them
    try:
        for i, (points, t_ns) in enumerate(zip(clouds, times_ns, strict=False)):
            points = np.asarray(points, np.float32).reshape(-1, 3)
            writer.append(
                i,
                int(t_ns),
                points,
                np.zeros((len(points), 3), np.uint8),
                {
                    "valid_fraction": float(np.isfinite(points).all(axis=1).mean())
                    if len(points)
                    else 0.0,
                    "disparity_px": np.full(4, np.nan),
                    "match_counts": np.full(4, -1, np.int64),
                    "decoded_fraction": np.nan,
                    "edge_fraction": np.nan,
                },
            )
        writer.finish()
        with h5py.File(tmp, "a") as f:
            labels = f.create_group(LABELS_GROUP)
            force = labels.create_dataset("force_n", data=np.asarray(forces_n, np.float64))
            force.attrs.update({"units": "N", "axes": ["x", "y", "z"]})
            labels.attrs["conditions_json"] = json.dumps(conditions)
    except BaseException:
        writer.abort()
        tmp.unlink(missing_ok=True)
        raise
    return commit(tmp, out)


def _depth_clouds(files: Sequence[Path], camera: DepthCamera) -> Iterator[np.ndarray]:
    first = read_depth(files[0])
    camera.check(first.shape[1], first.shape[0])
    for path in files:
        depth = read_depth(path)
        if depth.shape != first.shape:
            raise EstimateError(
                f"{path} is {depth.shape[1]}x{depth.shape[0]} but {files[0].name} "
                f"is {first.shape[1]}x{first.shape[0]}; depth frames of one "
                "recording must share one size (and camera)"
            )
        yield camera.points(depth)


def _in_range(points: np.ndarray, depth_range_m: tuple[float, float]) -> np.ndarray:
    """Finite points whose depth (z) lies within ``depth_range_m``."""
    z = points[:, 2]
    keep = np.isfinite(points).all(axis=1) & (z >= depth_range_m[0]) & (z <= depth_range_m[1])
    return points[keep]


def import_frames(
    kind: str,
    folder: str | Path,
    out: str | Path,
    forces: ForceTable,
    fps: float | None = None,
    frame_times_csv: Path | None = None,
    frame_time_column: str | None = None,
    camera: DepthCamera | None = None,
    condition: str | None = None,
    depth_range_m: tuple[float, float] = (-math.inf, math.inf),
    overwrite: bool = False,
) -> tuple[Path, int, int]:
    """Import a ``"clouds"`` or ``"depth"`` folder; returns (file, frames, frames with force).

    Points whose depth (z, metres) is outside ``depth_range_m`` are dropped, as are depth
    pixels of 0 or 65535 (no depth)."""
    out = check_out(out, overwrite)
    if not depth_range_m[0] < depth_range_m[1]:
        raise EstimateError(
            f"--min-depth {depth_range_m[0]} must be below --max-depth {depth_range_m[1]}"
        )
    if kind == "depth":
        if camera is None:
            raise EstimateError(
                "depth frames need the intrinsics --fx --fy --cx --cy and --depth-scale"
            )
        files = frame_files(folder, ("*.png",))
        clouds = _depth_clouds(files, camera)
    else:
        files = frame_files(folder, ("*.ply", "*.npy"))
        clouds = (read_cloud(p) for p in files)
    times = frame_times(len(files), fps, frame_times_csv, frame_time_column, forces.time_unit)
    force = forces.forces_at(times)
    with_force = int(np.isfinite(force).all(axis=1).sum())
    if with_force == 0:
        raise EstimateError(
            f"no frame has a force from {forces.path}: check the time column "
            "and units (frame and force times must share a clock) or the frame "
            "column"
        )
    source = {
        "kind": kind,
        "folder": str(folder),
        "files": [p.name for p in files],
        "forces_csv": str(forces.path),
        "depth_range_m": [d if math.isfinite(d) else None for d in depth_range_m],
        "camera": None if camera is None else camera.__dict__,
    }
    conditions = {"label": condition} if condition else {}
    path = write_clouds(
        out, (_in_range(c, depth_range_m) for c in clouds), times, force, conditions, source
    )
    return path, len(files), with_force
