"""Per-frame reconstruction: rectify, SGBM, De Bruijn verification, z = fB/d point cloud."""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.drivers.projector.pattern import DEFAULT_FRINGES
from vbfe.recon.color import ColorModel
from vbfe.recon.decode import FringeDecoder
from vbfe.recon.errors import ReconError
from vbfe.recon.matching import SgbmParams, sgbm_disparity
from vbfe.recon.quality import ReconSettings, decoded_fraction, edge_fraction, params_for
from vbfe.recon.verify import verify_disparity


@dataclass(frozen=True)
class FrameCloud:
    """One frame's reconstruction, all in the rectified left camera frame.

    ``disparity`` (H×W float32 px, NaN where invalid), ``valid`` (H×W bool), ``points`` (N×3
    float32, metres; row-major order of the valid pixels), ``colors`` (N×3 uint8, **RGB**).
    Quality: ``counts`` of the verification (SGBM matches, kept, corrected, rejected),
    ``decoded_fraction`` of left pixels with a readable De Bruijn code (NaN without
    verification) and ``edge_fraction`` of SGBM matches at the disparity range's ends.
    """

    disparity: np.ndarray
    valid: np.ndarray
    points: np.ndarray
    colors: np.ndarray
    counts: dict[str, int] = field(default_factory=dict)
    decoded_fraction: float = float("nan")
    edge_fraction: float = 0.0


def disparity_to_points(disparity: np.ndarray, valid: np.ndarray, f_px: float, baseline_m: float,
                        cx: float, cy: float, doffs_px: float = 0.0) -> np.ndarray:
    """Points (N×3 float32, m) of the valid pixels in row-major order: ``z = fB/(d - doffs)``,
    ``x = (u-cx)z/f``, ``y = (v-cy)z/f``.

    ``doffs_px`` is the difference of the rectified principal points (left minus right), zero
    for the usual zero-disparity rectification.
    """
    flat = np.flatnonzero(valid)
    x_over_z, y_over_z = _ray_slopes(valid.shape, float(f_px), float(cx), float(cy))
    points = np.empty((len(flat), 3), np.float32)
    z = np.float32(f_px * baseline_m) / (disparity.ravel().take(flat) - np.float32(doffs_px))
    points[:, 2] = z
    points[:, 0] = x_over_z.take(flat) * z
    points[:, 1] = y_over_z.take(flat) * z
    return points


@functools.lru_cache(maxsize=4)
def _ray_slopes(shape: tuple[int, int], f_px: float, cx: float, cy: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """``(u - cx) / f`` and ``(v - cy) / f`` of every pixel, flattened (built once per camera)."""
    v, u = np.indices(shape, np.float32)
    return ((u - np.float32(cx)) / np.float32(f_px)).ravel(), \
        ((v - np.float32(cy)) / np.float32(f_px)).ravel()


class Reconstructor:
    """Reconstructs stereo frames with one calibration and one set of SGBM settings.

    A zero ``num_disparities`` is derived from the calibration's ``f·B`` and the depth range of
    ``settings`` (the ``[recon]`` table); ``params`` holds the settings actually used.
    """

    def __init__(self, calibration: Calibration, sgbm_params: SgbmParams | None = None,
                 verify: bool = True, n_fringes: int = DEFAULT_FRINGES,
                 settings: ReconSettings | None = None) -> None:
        self.calibration = calibration
        self.settings = settings or ReconSettings()
        self.params = params_for(calibration, sgbm_params or SgbmParams(), self.settings)
        self.verify = verify
        self.decoder = FringeDecoder(ColorModel.from_calibration(calibration), n_fringes,
                                     row_step=self.params.decode_row_step)
        self._matcher = self.params.create(3)
        self._pool: ThreadPoolExecutor | None = None
        self._doffs = -calibration.doffs  # left minus right principal point x
        # computed once, in OpenCV's fast fixed-point form, reused for every frame
        self._maps = [cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
                      for map_x, map_y in calibration.rectification_maps()]

    def _overlap(self) -> ThreadPoolExecutor:
        """The one background thread SGBM runs in while the codes are decoded."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sgbm")
        return self._pool

    def _check_size(self, left: np.ndarray, right: np.ndarray) -> None:
        width, height = self.calibration.image_size
        for name, image in (("left", left), ("right", right)):
            if image.ndim != 3 or image.shape[:2] != (height, width):
                raise ReconError(
                    f"{name} image is {image.shape[1]}x{image.shape[0]} (shape {image.shape}) but "
                    f"the calibration is for {width}x{height} BGR images; use the calibration of "
                    f"this camera and resolution")

    def rectified_disparity(self, left: np.ndarray, right: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, float]]:
        """Rectified left image, disparity (px, NaN invalid), valid mask and quality: the
        verification counts, ``decoded_fraction`` and ``edge_fraction``."""
        self._check_size(left, right)
        rect_left, rect_right = (cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR)
                                 for image, (map_x, map_y) in zip((left, right), self._maps))
        if not self.verify:
            disparity = sgbm_disparity(rect_left, rect_right, self.params, self._matcher)
            return rect_left, disparity, np.isfinite(disparity), {
                "edge_fraction": edge_fraction(disparity, self.params)}
        # with several OpenCV threads, decode while SGBM runs (both release the GIL): the
        # single-threaded decoding then shares the cores SGBM leaves idle
        matching = self._overlap().submit(sgbm_disparity, rect_left, rect_right, self.params,
                                          self._matcher) if cv2.getNumThreads() > 1 else None
        left_code = self.decoder.decode(rect_left)
        right_code = self.decoder.decode(rect_right, period_px=left_code.period_px)
        disparity = (matching.result() if matching is not None else
                     sgbm_disparity(rect_left, rect_right, self.params, self._matcher))
        quality = {"edge_fraction": edge_fraction(disparity, self.params)}
        disparity, valid, counts = verify_disparity(disparity, left_code, right_code,
                                                    self.params.verify_search_px)
        quality["decoded_fraction"] = decoded_fraction(left_code.index)
        return rect_left, disparity, valid, {**quality, **counts}

    def process(self, left: np.ndarray, right: np.ndarray) -> FrameCloud:
        """Point cloud of one raw (unrectified) BGR stereo pair."""
        rect_left, disparity, valid, quality = self.rectified_disparity(left, right)
        if self.params.min_disparity <= self._doffs:  # some matches at or beyond infinity
            valid &= disparity > self._doffs
            disparity = np.where(valid, disparity, np.float32(np.nan))
        cal = self.calibration
        points = disparity_to_points(disparity, valid, cal.f, cal.B, cal.cx, cal.cy, self._doffs)
        colors = cv2.cvtColor(rect_left, cv2.COLOR_BGR2RGB).reshape(-1, 3).take(
            np.flatnonzero(valid), axis=0)
        counts = {k: int(v) for k, v in quality.items() if not k.endswith("_fraction")}
        return FrameCloud(disparity=disparity, valid=valid, points=points, colors=colors,
                          counts=counts,
                          decoded_fraction=quality.get("decoded_fraction", float("nan")),
                          edge_fraction=quality["edge_fraction"])
