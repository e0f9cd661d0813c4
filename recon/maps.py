"""Per-frame disparity and depth maps on the rectified left pixel grid.

PNG maps are 16-bit single-channel with 0 meaning "no value":

- ``<name>_disparity.png``: disparity in px = value / 256 (the KITTI convention, up to 255.99 px)
- ``<name>_depth.png``: depth z in mm = value / 10 (0.1 mm steps, up to 6.55 m)

NPY maps (``<name>_disparity.npy`` in px, ``<name>_depth.npy`` in m) are float32 with NaN where
there is no value. ``<name>_quality.png`` (8-bit, both formats) holds what matching and
verification did per pixel: 0 no match, 1 rejected by the De Bruijn check, 2 SGBM's match kept
unverified (pattern not readable there, or ``--no-verify``), 3 verified, 4 corrected by the check
(:mod:`vbfe.recon.kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.common.errors import ReconError

DISPARITY_PNG_SCALE = 256.0  # PNG value per pixel of disparity
DEPTH_PNG_SCALE = 10.0  # PNG value per millimetre of depth
MAP_FORMATS = ("png", "npy")


@dataclass(frozen=True)
class MapOutput:
    """Where and how to write per-frame disparity and depth maps."""

    folder: Path
    fmt: str = "png"  # "png" (16-bit, fixed scale) or "npy" (float32)

    def __post_init__(self) -> None:
        if self.fmt not in MAP_FORMATS:
            raise ReconError(f"map format must be one of {MAP_FORMATS}, got {self.fmt!r}")


def depth_map_m(disparity: np.ndarray, calibration: Calibration) -> np.ndarray:
    """Depth ``z = f·B/(d - disparity_offset)`` (m, float32, NaN where the disparity is missing
    or at or beyond infinity)."""
    shifted = disparity.astype(np.float32) - np.float32(calibration.disparity_offset)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(
            shifted > 0, np.float32(calibration.f * calibration.B) / shifted, np.float32(np.nan)
        ).astype(np.float32)


def _to_png(values: np.ndarray, scale: float) -> np.ndarray:
    scaled = np.where(np.isfinite(values), np.rint(values * scale), 0)
    return np.clip(scaled, 0, 65535).astype(np.uint16)


def write_maps(
    folder: Path,
    name: str,
    disparity: np.ndarray,
    calibration: Calibration,
    fmt: str = "png",
    status: np.ndarray | None = None,
) -> list[Path]:
    """Write ``<name>_disparity`` and ``<name>_depth`` maps in ``fmt`` into ``folder``, and
    the per-pixel outcome ``status`` as ``<name>_quality.png`` when given."""
    folder.mkdir(parents=True, exist_ok=True)
    depth = depth_map_m(disparity, calibration)
    written = []
    for kind, values, scale in (
        ("disparity", disparity, DISPARITY_PNG_SCALE),
        ("depth", depth * np.float32(1e3), DEPTH_PNG_SCALE),
    ):
        path = folder / f"{name}_{kind}.{fmt}"
        if fmt == "npy":
            np.save(path, depth if kind == "depth" else values.astype(np.float32))
        elif not cv2.imwrite(str(path), _to_png(values, scale)):
            raise ReconError(f"cannot write {path}; check the folder is writable")
        written.append(path)
    if status is not None:
        path = folder / f"{name}_quality.png"
        if not cv2.imwrite(str(path), status):
            raise ReconError(f"cannot write {path}; check the folder is writable")
        written.append(path)
    return written


def read_png_map(path: str | Path, kind: str) -> np.ndarray:
    """A PNG map written by :func:`write_maps` back in px (disparity) or m (depth), NaN = none."""
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.dtype != np.uint16:
        raise ReconError(f"{path} is not a 16-bit PNG map")
    scale = DISPARITY_PNG_SCALE if kind == "disparity" else DEPTH_PNG_SCALE * 1e3
    return np.where(raw > 0, raw / scale, np.nan).astype(np.float32)
