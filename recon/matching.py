"""Initial matching: OpenCV StereoSGBM on rectified pairs, settings from the rig's [sgbm] table."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import cv2
import numpy as np

from vbfe.recon.errors import ReconError

MODES = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
         "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "hh4": cv2.STEREO_SGBM_MODE_HH4}
DISPARITY_SCALE = 16.0  # StereoSGBM returns fixed-point disparities with 4 fractional bits


@dataclass(frozen=True)
class SgbmParams:
    """StereoSGBM settings; ``p1``/``p2`` = 0 pick OpenCV's usual 8·3·b² and 32·3·b²;
    ``num_disparities`` = 0 derives ``min_disparity`` and the range from the calibration and
    the rig's depth range (:func:`vbfe.recon.quality.params_for`)."""

    min_disparity: int = 0
    num_disparities: int = 0
    block_size: int = 5
    uniqueness_ratio: int = 5
    speckle_window_size: int = 100
    speckle_range: int = 2
    disp12_max_diff: int = 1
    p1: int = 0
    p2: int = 0
    pre_filter_cap: int = 63
    mode: str = "sgbm_3way"
    verify_search_px: int = 3  # ± pixels searched along the row when verification rejects a match
    decode_row_step: int = 3  # De Bruijn codes are decoded on every n-th row and copied below

    @classmethod
    def from_config(cls, table: dict[str, Any]) -> "SgbmParams":
        """Settings from the ``[sgbm]`` table of a rig config (unknown keys are an error)."""
        check_known_keys("sgbm", table, cls)
        params = cls(**table)
        if params.num_disparities < 0 or params.num_disparities % 16:
            raise ReconError(f"[sgbm] num_disparities must be 0 (from the depth range) or a "
                             f"positive multiple of 16, got "
                             f"{params.num_disparities}")
        if params.block_size < 1 or params.block_size % 2 == 0:
            raise ReconError(f"[sgbm] block_size must be odd and positive, got {params.block_size}")
        if params.decode_row_step < 1:
            raise ReconError(f"[sgbm] decode_row_step must be >= 1, got {params.decode_row_step}")
        if params.mode not in MODES:
            raise ReconError(f"[sgbm] mode must be one of {sorted(MODES)}, got {params.mode!r}")
        return params

    def create(self, channels: int = 3) -> cv2.StereoSGBM:
        """A configured ``cv2.StereoSGBM`` matcher for images with ``channels`` channels."""
        if self.num_disparities <= 0:
            raise ReconError("num_disparities is 0 (derive from the geometry): resolve it with "
                             "vbfe.recon.quality.params_for(calibration, params, settings)")
        area = channels * self.block_size ** 2
        return cv2.StereoSGBM.create(
            minDisparity=self.min_disparity, numDisparities=self.num_disparities,
            blockSize=self.block_size, P1=self.p1 or 8 * area, P2=self.p2 or 32 * area,
            disp12MaxDiff=self.disp12_max_diff, preFilterCap=self.pre_filter_cap,
            uniquenessRatio=self.uniqueness_ratio, speckleWindowSize=self.speckle_window_size,
            speckleRange=self.speckle_range, mode=MODES[self.mode])


def check_known_keys(name: str, table: dict[str, Any], settings: type) -> None:
    """Refuse keys of config table ``[name]`` that are not fields of the ``settings`` dataclass."""
    known = {f.name for f in fields(settings)}
    unknown = set(table) - known
    if unknown:
        raise ReconError(f"[{name}] table has unknown key(s) {sorted(unknown)}; "
                         f"known: {sorted(known)}")


def sgbm_disparity(left: np.ndarray, right: np.ndarray, params: SgbmParams,
                   matcher: cv2.StereoSGBM | None = None) -> np.ndarray:
    """Left-view disparity in pixels (float32); pixels without a match are ``NaN``."""
    matcher = matcher or params.create(left.shape[2] if left.ndim == 3 else 1)
    raw = matcher.compute(left, right)
    disparity = raw.astype(np.float32) / DISPARITY_SCALE
    disparity[raw < params.min_disparity * DISPARITY_SCALE] = np.nan
    return disparity
