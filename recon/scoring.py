"""Scoring a disparity map against external ground truth, in the conventions labs use.

Truth files (on the rectified left pixel grid):

- Middlebury PFM (``disp0.pfm``, ``disp0GT.pfm``): float disparity in px, ``inf`` = unknown;
  depth PFMs hold millimetres. The ``calib.txt`` beside it gives the geometry
  (:func:`vbfe.recon.inputs.middlebury_calibration`).
- PNG, 8- or 16-bit: value = scale · disparity (px) or scale · depth (mm), 0 = unknown
  (Middlebury 2001: scale 8, 2003 quarter size: 4, KITTI and vbfe's own maps: 256 for
  disparity, vbfe's depth maps: 10 per mm).

The scores follow the Middlebury evaluation: over the pixels with known truth, the density (share
with an estimate), the bad-pixel rates ``|d - d_true| > 1, 2, 3 px`` over all of them (a
missing estimate counts as bad) and over the estimated ones only, and the mean absolute error in
px and in mm of depth (``z = f·B/(d - doffs)``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.common.errors import ReconError

BAD_THRESHOLDS_PX = (1.0, 2.0, 3.0)
TRUTH_KINDS = ("disparity", "depth")
DEFAULT_PNG_SCALE: dict[tuple[str, np.dtype], float] = {
    ("disparity", np.dtype(np.uint16)): 256.0,
    ("depth", np.dtype(np.uint16)): 10.0,
}


def read_pfm(path: str | Path) -> np.ndarray:
    """A greyscale PFM image (float32, top row first; PFM stores the bottom row first)."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ReconError(f"cannot read {path}: {exc}") from None
    header = re.match(rb"Pf\s+(\d+)\s+(\d+)\s+(-?[\d.eE+-]+)\s", data)
    if header is None:
        raise ReconError(f"{path} is not a greyscale PFM file (header 'Pf width height scale')")
    width, height, scale = int(header[1]), int(header[2]), float(header[3])
    dtype = np.dtype("<f4" if scale < 0 else ">f4")
    values = (
        np.frombuffer(data, dtype, count=width * height, offset=header.end())
        if len(data) - header.end() >= 4 * width * height
        else None
    )
    if values is None:
        raise ReconError(
            f"{path} is truncated: a {width}x{height} PFM needs {4 * width * height} bytes of data"
        )
    return np.flipud(values.reshape(height, width)).astype(np.float32)


def read_truth(path: str | Path, kind: str = "disparity", scale: float | None = None) -> np.ndarray:
    """A truth map in px (disparity) or mm (depth), float32, NaN where unknown."""
    path = Path(path)
    if kind not in TRUTH_KINDS:
        raise ReconError(f"truth kind must be one of {TRUTH_KINDS}, got {kind!r}")
    if path.suffix.lower() == ".pfm":
        values = read_pfm(path)
        return np.where(np.isfinite(values) & (values > 0), values, np.nan).astype(np.float32)
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.ndim != 2 or raw.dtype not in (np.uint8, np.uint16):
        raise ReconError(f"{path} is not a single-channel 8- or 16-bit PNG truth map (or a PFM)")
    scale = scale or DEFAULT_PNG_SCALE.get((kind, raw.dtype))
    if not scale or scale <= 0:
        raise ReconError(
            f"{path} is an 8-bit {kind} map: give its scale with --truth-scale "
            f"(value = scale x {'px' if kind == 'disparity' else 'mm'}; Middlebury "
            f"2003 quarter size: 4, 2001: 8)"
        )
    return np.where(raw > 0, raw / scale, np.nan).astype(np.float32)


def truth_disparity(
    path: str | Path, calibration: Calibration, kind: str = "disparity", scale: float | None = None
) -> np.ndarray:
    """The truth as disparity (px, NaN unknown), a depth truth converted with the geometry."""
    values = read_truth(path, kind, scale)
    width, height = calibration.image_size
    if values.shape != (height, width):
        raise ReconError(
            f"truth {path} is {values.shape[1]}x{values.shape[0]} but the images "
            f"are {width}x{height}; give the truth of this pair's left view"
        )
    if kind == "depth":
        return (
            np.float32(calibration.f * calibration.B * 1e3) / values
            + np.float32(_doffs(calibration))
        ).astype(np.float32)
    return values


def _doffs(calibration: Calibration) -> float:
    """Left minus right rectified principal point x (px): ``z = f·B/(d - doffs)``."""
    return float(calibration.P1[0, 2] - calibration.P2[0, 2])


@dataclass(frozen=True)
class TruthScore:
    """Scores of one disparity map against its truth (rates are fractions, not percent)."""

    n_truth: int  # pixels with known truth
    density: float  # share of them with an estimate
    bad_all: tuple[float, ...]  # |error| > each of BAD_THRESHOLDS_PX, missing counts as bad
    bad_valid: tuple[float, ...]  # the same over the estimated pixels only
    mae_px: float  # over the estimated pixels
    mae_mm: float  # depth, over the estimated pixels in front of the camera in both maps

    def lines(self) -> list[str]:
        """The scores as the Middlebury evaluation prints them (percent)."""
        head = "  ".join(f"bad>{t:g}" for t in BAD_THRESHOLDS_PX)
        return [
            f"truth: {self.n_truth} known pixels, density {self.density:.2%}",
            f"  {'':12s}{head}",
            "  all         " + "  ".join(f"{100 * v:5.2f}" for v in self.bad_all),
            "  valid-only  " + "  ".join(f"{100 * v:5.2f}" for v in self.bad_valid),
            f"  mean abs error {self.mae_px:.3f} px, {self.mae_mm:.3f} mm",
        ]


def score_disparity(
    estimate: np.ndarray, truth: np.ndarray, calibration: Calibration
) -> TruthScore:
    """Score ``estimate`` (px, NaN where missing) against ``truth`` (px, NaN unknown)."""
    if estimate.shape != truth.shape:
        raise ReconError(f"estimate is {estimate.shape} but the truth is {truth.shape}")
    known = np.isfinite(truth)
    n_truth = int(known.sum())
    if not n_truth:
        raise ReconError("the truth map has no known pixel (0 or inf everywhere)")
    both = known & np.isfinite(estimate)
    error = np.abs(estimate[both].astype(np.float64) - truth[both])
    n_both = max(len(error), 1)
    f_b_mm = calibration.f * calibration.B * 1e3
    doffs = _doffs(calibration)
    shifted_est, shifted_true = estimate[both] - doffs, truth[both] - doffs
    front = (shifted_est > 0) & (shifted_true > 0)
    depth_error = np.abs(f_b_mm / shifted_est[front] - f_b_mm / shifted_true[front])
    return TruthScore(
        n_truth=n_truth,
        density=len(error) / n_truth,
        bad_all=tuple(
            float(np.count_nonzero(error > t) + n_truth - len(error)) / n_truth
            for t in BAD_THRESHOLDS_PX
        ),
        bad_valid=tuple(float(np.count_nonzero(error > t)) / n_both for t in BAD_THRESHOLDS_PX),
        mae_px=float(error.mean()) if len(error) else float("nan"),
        mae_mm=float(depth_error.mean()) if len(depth_error) else float("nan"),
    )
