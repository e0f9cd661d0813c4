"""Initial matching: OpenCV StereoSGBM on rectified pairs, settings from the rig's [sgbm] table."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np

from vbfe.common.errors import ReconError
from vbfe.common.settings import parse_table, setting
from vbfe.recon import kernels

MODES = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}
MODE_NAMES = tuple(MODES)
DISPARITY_SCALE = 16.0  # StereoSGBM returns fixed-point disparities with 4 fractional bits


@dataclass(frozen=True)
class SgbmParams:
    """StereoSGBM settings; ``p1``/``p2`` = 0 pick OpenCV's usual 8·3·b² and 32·3·b²;
    ``num_disparities`` = 0 derives ``min_disparity`` and the range from the calibration and
    the rig's depth range (:func:`vbfe.recon.quality.params_for`)."""

    min_disparity: int = 0
    num_disparities: int = setting(0, ge=0)  # 0: derived from the geometry (recon.quality)
    block_size: int = setting(5, ge=1)
    uniqueness_ratio: int = setting(5, ge=0)
    speckle_window_size: int = setting(100, ge=0)
    speckle_range: int = setting(2, ge=0)
    disp12_max_diff: int = 1
    p1: int = setting(0, ge=0)
    p2: int = setting(0, ge=0)
    pre_filter_cap: int = setting(63, ge=0)
    # a Literal of a tuple's values: the settings parser reads them; mypy cannot
    mode: Literal[MODE_NAMES] = "sgbm_3way"  # type: ignore[valid-type]
    # ± pixels searched along the row when verification rejects a match
    verify_search_px: int = setting(3, ge=0)
    # De Bruijn codes are decoded on the middle row of each block of n rows and copied to the rest
    decode_row_step: int = setting(5, ge=1)

    @classmethod
    def from_config(cls, table: dict[str, Any]) -> SgbmParams:
        """Settings from the ``[sgbm]`` table of a rig config (unknown keys are an error)."""
        params = parse_table(cls, table, "sgbm")
        if params.num_disparities % 16:
            raise ReconError(
                f"[sgbm] num_disparities (--num-disparities) must be 0 (from the "
                f"depth range) or a positive multiple of 16, got "
                f"{params.num_disparities}"
            )
        if params.p1 and params.p2 and params.p2 <= params.p1:
            raise ReconError(
                f"[sgbm] p2 = {params.p2} must be larger than p1 = {params.p1} "
                "(OpenCV's smoothness penalties; 0 picks both)"
            )
        if params.block_size < 1 or params.block_size % 2 == 0:
            raise ReconError(f"[sgbm] block_size must be odd and positive, got {params.block_size}")
        return params

    def create(self, channels: int = 3) -> cv2.StereoSGBM:
        """A configured ``cv2.StereoSGBM`` matcher for images with ``channels`` channels."""
        if self.num_disparities <= 0:
            raise ReconError(
                "num_disparities is 0 (derive from the geometry): resolve it with "
                "vbfe.recon.quality.params_for(calibration, params, settings)"
            )
        area = channels * self.block_size**2
        return cv2.StereoSGBM.create(
            minDisparity=self.min_disparity,
            numDisparities=self.num_disparities,
            blockSize=self.block_size,
            P1=self.p1 or 8 * area,
            P2=self.p2 or 32 * area,
            disp12MaxDiff=self.disp12_max_diff,
            preFilterCap=self.pre_filter_cap,
            uniquenessRatio=self.uniqueness_ratio,
            speckleWindowSize=self.speckle_window_size,
            speckleRange=self.speckle_range,
            mode=MODES[self.mode],
        )


def sgbm_disparity(
    left: np.ndarray, right: np.ndarray, params: SgbmParams, matcher: cv2.StereoSGBM | None = None
) -> np.ndarray:
    """Left-view disparity in pixels (float32); pixels without a match are ``NaN``."""
    matcher = matcher or params.create(left.shape[2] if left.ndim == 3 else 1)
    return disparity_px(matcher.compute(left, right), params)[0]


def disparity_px(raw: np.ndarray, params: SgbmParams) -> tuple[np.ndarray, float]:
    """StereoSGBM's fixed-point output in pixels (float32), ``NaN`` where it found no match, and
    the share of matched pixels within one pixel of either end of the disparity range (edge
    share): surfaces nearer or farther than the range covers pile up there (or are lost)."""
    disparity = np.empty(raw.shape, np.float32)
    low = params.min_disparity
    high = params.min_disparity + params.num_disparities - 1
    # d <= low + 1 is raw <= (low + 1)·scale exactly (raw / scale is exact in float32)
    low_raw, edge_low, edge_high = (np.int16(v * DISPARITY_SCALE) for v in (low, low + 1, high - 1))
    matched, at_edge = kernels.fixed_point_to_px(
        raw, 1.0 / DISPARITY_SCALE, low_raw, edge_low, edge_high, disparity
    )
    return disparity, float(at_edge / matched) if matched else 0.0
