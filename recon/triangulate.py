"""Per-frame reconstruction: rectify, SGBM, De Bruijn verification, z = fB/(d - doffs) cloud."""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.drivers.projector.pattern import DEFAULT_FRINGES
from vbfe.recon import kernels
from vbfe.recon.color import ColorModel
from vbfe.recon.decode import FringeCode, FringeDecoder
from vbfe.recon.errors import ReconError
from vbfe.recon.kernels import NO_MATCH, UNVERIFIED
from vbfe.recon.matching import SgbmParams, sgbm_disparity
from vbfe.recon.quality import (ReconSettings, check_disparity_range, decoded_fraction,
                                edge_fraction, params_for)
from vbfe.recon.verify import CodedGrid, coded_grid, verify_disparity


@dataclass(frozen=True)
class FrameCloud:
    """One frame's reconstruction, all in the rectified left camera frame.

    ``disparity`` (H×W float32 px, NaN where invalid), ``valid`` (H×W bool), ``points`` (N×3
    float32, metres; row-major order of the valid pixels), ``colors`` (N×3 uint8, **RGB**),
    ``verified`` (N bool: the point's match agrees with the De Bruijn code) and ``status``
    (H×W uint8, the outcome per pixel: ``NO_MATCH``, ``REJECTED``, ``UNVERIFIED``, ``KEPT``
    or ``CORRECTED`` of :mod:`vbfe.recon.kernels`). Quality: ``counts`` of the verification
    (SGBM matches, kept, corrected, rejected, unverified), ``decoded_fraction`` of left pixels
    with a readable De Bruijn code (NaN without verification) and ``edge_fraction`` of SGBM
    matches at the disparity range's ends.
    """

    disparity: np.ndarray
    valid: np.ndarray
    points: np.ndarray
    colors: np.ndarray
    verified: np.ndarray
    status: np.ndarray
    counts: dict[str, int] = field(default_factory=dict)
    decoded_fraction: float = float("nan")
    edge_fraction: float = 0.0


def _fixed_point_map(map_x: np.ndarray, map_y: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray] | None:
    """OpenCV's fixed-point form of a remap, or None when it copies every pixel to itself."""
    xy, fraction = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
    grid = np.indices(map_x.shape, np.int16)[::-1].transpose(1, 2, 0)
    return None if not fraction.any() and np.array_equal(xy, grid) else (xy, fraction)


class Reconstructor:
    """Reconstructs stereo frames with one calibration and one set of SGBM settings.

    A zero ``num_disparities`` is derived from the calibration's ``f·B`` and the depth range of
    ``settings`` (the ``[recon]`` table); ``params`` holds the settings actually used. The two
    views are decoded on two threads at once when ``parallel_decode`` is true (default: when
    OpenCV has several threads).
    """

    def __init__(self, calibration: Calibration, sgbm_params: SgbmParams | None = None,
                 verify: bool = True, n_fringes: int = DEFAULT_FRINGES,
                 settings: ReconSettings | None = None,
                 parallel_decode: bool | None = None) -> None:
        self.calibration = calibration
        self.settings = settings or ReconSettings()
        self.params = params_for(calibration, sgbm_params or SgbmParams(), self.settings)
        check_disparity_range(self.params, calibration.image_size)
        self.verify = verify
        self.parallel_decode = parallel_decode
        self.decoder = FringeDecoder(ColorModel.from_calibration(calibration), n_fringes,
                                     row_step=self.params.decode_row_step)
        self._matcher = self.params.create(3)
        self._pool: ThreadPoolExecutor | None = None
        self._doffs = -calibration.doffs  # left minus right principal point x
        # computed once, in OpenCV's fast fixed-point form, reused for every frame; None
        # where rectification leaves the image as it is (an already-rectified pair)
        self._maps = [_fixed_point_map(map_x, map_y)
                      for map_x, map_y in calibration.rectification_maps()]
        kernels.warm_up()

    def _second_thread(self) -> ThreadPoolExecutor | None:
        """The thread the right view is decoded in while the left is decoded here (None without
        ``parallel_decode``: everything then runs in the calling thread)."""
        parallel = (cv2.getNumThreads() > 1 if self.parallel_decode is None
                    else self.parallel_decode)
        if not parallel:
            return None
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="decode")
        return self._pool

    def _check_size(self, left: np.ndarray, right: np.ndarray) -> None:
        width, height = self.calibration.image_size
        for name, image in (("left", left), ("right", right)):
            if image.ndim != 3 or image.shape[:2] != (height, width):
                raise ReconError(
                    f"{name} image is {image.shape[1]}x{image.shape[0]} (shape {image.shape}) but "
                    f"the calibration is for {width}x{height} BGR images; use the calibration of "
                    f"this camera and resolution")

    def _rectify(self, image: np.ndarray, maps: tuple[np.ndarray, np.ndarray] | None
                 ) -> np.ndarray:
        return image if maps is None else cv2.remap(image, *maps, cv2.INTER_LINEAR)

    def _decode(self, left: np.ndarray, right: np.ndarray
                ) -> tuple[FringeCode, FringeCode, CodedGrid, float]:
        """Fringe codes of both rectified views (the right with the left's fringe width), the
        left's coded region and its share of readable pixels. The two views are decoded at once
        where OpenCV has several threads (the kernels release the GIL), before SGBM rather than
        beside it: SGBM splits its rows evenly between the cores, so work beside it holds up
        one half while the other waits."""
        period = self.decoder.period_px(left)
        pool = self._second_thread()
        right_code = pool.submit(self.decoder.decode, right, period) if pool else None
        left_code = self.decoder.decode(left, period)
        coded, decoded = coded_grid(left_code), decoded_fraction(left_code.index)
        return (left_code, right_code.result() if pool else self.decoder.decode(right, period),
                coded, decoded)

    def rectified_disparity(self, left: np.ndarray, right: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, float]]:
        """Rectified left image, disparity (px, NaN invalid), outcome per pixel (the status
        codes of :mod:`vbfe.recon.kernels`) and quality: the verification counts,
        ``decoded_fraction`` and ``edge_fraction``."""
        self._check_size(left, right)
        rect_left, rect_right = (self._rectify(image, maps)
                                 for image, maps in zip((left, right), self._maps))
        if not self.verify:
            disparity = sgbm_disparity(rect_left, rect_right, self.params, self._matcher)
            status = np.where(np.isfinite(disparity), np.uint8(UNVERIFIED), np.uint8(NO_MATCH))
            return rect_left, disparity, status, {
                "edge_fraction": edge_fraction(disparity, self.params)}
        left_code, right_code, coded, decoded = self._decode(rect_left, rect_right)
        disparity = sgbm_disparity(rect_left, rect_right, self.params, self._matcher)
        quality = {"edge_fraction": edge_fraction(disparity, self.params),
                   "decoded_fraction": decoded}
        disparity, status, counts = verify_disparity(disparity, left_code, right_code,
                                                     self.params.verify_search_px, coded,
                                                     self._second_thread())
        return rect_left, disparity, status, {**quality, **counts}

    def _triangulate(self, rect_left: np.ndarray, disparity: np.ndarray, status: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`vbfe.recon.kernels.triangulate`; with a second thread, the lower half of the
        rows is counted and filled in it (the same points, in the same order)."""
        cal = self.calibration
        camera = (cal.f, cal.B, cal.cx, cal.cy, self._doffs, cal.fy)
        pool = self._second_thread()
        if pool is None:
            return kernels.triangulate(disparity, status, rect_left, *camera)
        height = disparity.shape[0]
        split = height // 2
        lower = pool.submit(kernels.count_points, disparity, status, self._doffs, split, height)
        n_upper = kernels.count_points(disparity, status, self._doffs, 0, split)
        n = n_upper + lower.result()
        points, colors, verified = (np.empty((n, 3), np.float32), np.empty((n, 3), np.uint8),
                                    np.empty(n, bool))
        fill = functools.partial(kernels.fill_points, disparity, status, rect_left, *camera)
        lower = pool.submit(fill, split, height, points, colors, verified, n_upper)
        fill(0, split, points, colors, verified, 0)
        lower.result()
        return points, colors, verified

    def process(self, left: np.ndarray, right: np.ndarray) -> FrameCloud:
        """Point cloud of one raw (unrectified) BGR stereo pair."""
        rect_left, disparity, status, quality = self.rectified_disparity(left, right)
        points, colors, verified = self._triangulate(rect_left, disparity, status)
        counts = {k: int(v) for k, v in quality.items() if not k.endswith("_fraction")}
        return FrameCloud(disparity=disparity, valid=status >= UNVERIFIED, points=points,
                          colors=colors, verified=verified, status=status, counts=counts,
                          decoded_fraction=quality.get("decoded_fraction", float("nan")),
                          edge_fraction=quality["edge_fraction"])
