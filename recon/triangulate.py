"""Per-frame reconstruction: rectify, SGBM, De Bruijn verification, the z = fB/(d - d_inf) cloud."""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.common.errors import ReconError
from vbfe.drivers.projector.pattern import DEFAULT_FRINGES
from vbfe.recon import kernels
from vbfe.recon.color import ColorModel
from vbfe.recon.decode import FringeCode, FringeDecoder
from vbfe.recon.kernels import NO_MATCH, UNVERIFIED
from vbfe.recon.matching import DISPARITY_SCALE, SgbmParams, disparity_px
from vbfe.recon.quality import (
    ReconSettings,
    check_disparity_range,
    decoded_fraction,
    narrowed,
    params_for,
)
from vbfe.recon.verify import COUNT_NAMES, CodedGrid, coded_grid, verify_rows


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


def _fixed_point_map(map_x: np.ndarray, map_y: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """OpenCV's fixed-point form of a remap, or None when it copies every pixel to itself."""
    xy, fraction = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
    grid = np.indices(map_x.shape, np.int16)[::-1].transpose(1, 2, 0)
    return None if not fraction.any() and np.array_equal(xy, grid) else (xy, fraction)


def _coded_region(code: FringeCode) -> tuple[CodedGrid, float]:
    """The coded region of a view and its share of readable pixels."""
    return coded_grid(code), decoded_fraction(code.index, code.row_step)


class Reconstructor:
    """Reconstructs stereo frames with one calibration and one set of SGBM settings.

    A zero ``num_disparities`` is derived from the calibration's ``f·B`` and the depth range of
    ``settings`` (the ``[recon]`` table); ``params`` holds the settings actually used. The two
    views are decoded on two threads at once when ``parallel_decode`` is true (default: when
    OpenCV has several threads). :meth:`search_depths` narrows the search to the depths a
    scene is known to span (``vbfe live``: its rest frame's).
    """

    def __init__(
        self,
        calibration: Calibration,
        sgbm_params: SgbmParams | None = None,
        verify: bool = True,
        n_fringes: int = DEFAULT_FRINGES,
        settings: ReconSettings | None = None,
        parallel_decode: bool | None = None,
    ) -> None:
        self.calibration = calibration
        self.settings = settings or ReconSettings()
        self.params = params_for(calibration, sgbm_params or SgbmParams(), self.settings)
        check_disparity_range(self.params, calibration.image_size)
        self.verify = verify
        self.parallel_decode = parallel_decode
        self.decoder = FringeDecoder(
            ColorModel.from_calibration(calibration),
            n_fringes,
            row_step=self.params.decode_row_step,
        )
        # what SGBM searches (the settings, the matcher) and the columns left of which matches
        # are dropped (0: none); one tuple, read once per frame, swapped by search_depths
        self._search = (self.params, self.params.create(3), 0)
        self._pool: ThreadPoolExecutor | None = None
        self._disparity_offset = calibration.disparity_offset
        self._camera = (
            calibration.f,
            calibration.B,
            calibration.cx,
            calibration.cy,
            self._disparity_offset,
            calibration.fy,
        )
        # computed once, in OpenCV's fast fixed-point form, reused for every frame; None
        # where rectification leaves the image as it is (an already-rectified pair)
        self._maps = [
            _fixed_point_map(map_x, map_y) for map_x, map_y in calibration.rectification_maps()
        ]
        kernels.warm_up()

    def _second_thread(self) -> ThreadPoolExecutor | None:
        """The thread the right view is decoded in while the left is decoded here (None without
        ``parallel_decode``: everything then runs in the calling thread)."""
        parallel = cv2.getNumThreads() > 1 if self.parallel_decode is None else self.parallel_decode
        if not parallel:
            return None
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="decode")
        return self._pool

    @property
    def searched(self) -> SgbmParams:
        """The SGBM settings the next frame is matched with (``params`` or, after
        :meth:`search_depths`, a narrower range)."""
        return self._search[0]

    def search_depths(self, min_depth_mm: float, max_depth_mm: float) -> SgbmParams:
        """From the next frame on, search only the disparities of surfaces ``min_depth_mm`` to
        ``max_depth_mm`` away (within ``params``' range; SGBM's cost grows with the count);
        the pixels that ``params``' range leaves unmatched at the left edge stay unmatched,
        so the clouds keep their extent. Returns the settings searched (``params`` when the
        depths span no fewer disparities). Safe while another thread reconstructs."""
        searched = narrowed(self.calibration, self.params, min_depth_mm, max_depth_mm)
        if searched is None:
            self._search = (self.params, self.params.create(3), 0)
            return self.params
        blind = self.params.min_disparity + self.params.num_disparities
        self._search = (searched, searched.create(3), blind)
        return searched

    def _match(
        self, rect_left: np.ndarray, rect_right: np.ndarray
    ) -> tuple[np.ndarray, SgbmParams]:
        """SGBM's fixed-point disparity on the searched range, and the settings searched."""
        params, matcher, blind = self._search
        raw = matcher.compute(rect_left, rect_right)
        if blind:  # OpenCV's "no match" value
            raw[:, :blind] = (params.min_disparity - 1) * DISPARITY_SCALE
        return raw, params

    def _check_size(self, left: np.ndarray, right: np.ndarray) -> None:
        width, height = self.calibration.image_size
        for name, image in (("left", left), ("right", right)):
            if image.ndim != 3 or image.shape[:2] != (height, width):
                raise ReconError(
                    f"{name} image is {image.shape[1]}x{image.shape[0]} (shape {image.shape}) but "
                    f"the calibration is for {width}x{height} BGR images; use the calibration of "
                    f"this camera and resolution"
                )

    def _rectify(self, image: np.ndarray, maps: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
        return image if maps is None else cv2.remap(image, *maps, cv2.INTER_LINEAR)

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pair rectified as :meth:`process` rectifies it (the calibration's maps)."""
        (left_maps, right_maps) = self._maps
        return self._rectify(left, left_maps), self._rectify(right, right_maps)

    def _decode(self, left: np.ndarray, right: np.ndarray) -> tuple[FringeCode, FringeCode]:
        """Fringe codes of both rectified views (the right with the left's fringe width). The
        two views are decoded at once where OpenCV has several threads (the kernels release the
        GIL), before SGBM rather than beside it: SGBM splits its rows evenly between the cores,
        so work beside it holds up one half while the other waits."""
        period = self.decoder.period_px(left)
        pool = self._second_thread()
        right_code = pool.submit(self.decoder.decode, right, period) if pool else None
        left_code = self.decoder.decode(left, period)
        if right_code is not None:
            return left_code, right_code.result()
        return left_code, self.decoder.decode(right, period)

    def _verify_and_triangulate(
        self,
        rect_left: np.ndarray,
        disparity: np.ndarray,
        left_code: FringeCode,
        right_code: FringeCode,
        coded: CodedGrid,
    ) -> tuple[np.ndarray, np.ndarray, dict[str, int], tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Verified disparity, outcome per pixel, the verification's counts and the cloud:
        :func:`vbfe.recon.verify.verify_rows` (which also drops matches at or beyond infinity
        and counts the points) then :func:`vbfe.recon.kernels.fill_points`. With a second
        thread, the lower half of the rows is verified and filled in it (the same outcome, the
        points in the same order)."""
        out, status = np.empty_like(disparity), np.empty(disparity.shape, np.uint8)
        check = functools.partial(
            verify_rows,
            disparity,
            left_code,
            right_code,
            self.params.verify_search_px,
            coded,
            out=out,
            status=status,
            doffs_px=self._disparity_offset,
        )
        pool, height = self._second_thread(), disparity.shape[0]
        split = height // 2 if pool is not None else height
        lower = pool.submit(check, split, height) if pool is not None else None
        upper = check(0, split)
        counts = upper + lower.result() if lower is not None else upper
        cloud = self._fill(rect_left, out, status, split, int(upper[-1]), int(counts[-1]), pool)
        return out, status, dict(zip(COUNT_NAMES, (int(c) for c in counts), strict=False)), cloud

    def _triangulate(
        self, rect_left: np.ndarray, disparity: np.ndarray, status: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`vbfe.recon.kernels.triangulate`; with a second thread, the lower half of the
        rows is counted and filled in it (the same points, in the same order)."""
        pool = self._second_thread()
        if pool is None:
            return kernels.triangulate(disparity, status, rect_left, *self._camera)
        height = disparity.shape[0]
        split = height // 2
        lower = pool.submit(
            kernels.count_points, disparity, status, self._disparity_offset, split, height
        )
        n_upper = kernels.count_points(disparity, status, self._disparity_offset, 0, split)
        return self._fill(
            rect_left, disparity, status, split, n_upper, n_upper + lower.result(), pool
        )

    def _fill(
        self,
        rect_left: np.ndarray,
        disparity: np.ndarray,
        status: np.ndarray,
        split: int,
        n_upper: int,
        n: int,
        pool: ThreadPoolExecutor | None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ``n`` points, colours and verified flags of the counted pixels, those of rows
        from ``split`` on (after ``n_upper`` points) in ``pool``."""
        points, colors, verified = (
            np.empty((n, 3), np.float32),
            np.empty((n, 3), np.uint8),
            np.empty(n, bool),
        )
        fill = functools.partial(kernels.fill_points, disparity, status, rect_left, *self._camera)
        height = disparity.shape[0]
        lower = (
            pool.submit(fill, split, height, points, colors, verified, n_upper)
            if pool is not None and split < height
            else None
        )
        fill(0, split, points, colors, verified, 0)
        if lower is not None:
            lower.result()
        return points, colors, verified

    def process(self, left: np.ndarray, right: np.ndarray) -> FrameCloud:
        """Point cloud of one raw (unrectified) BGR stereo pair."""
        self._check_size(left, right)
        rect_left, rect_right = self.rectify(left, right)
        if not self.verify:
            disparity, edge = disparity_px(*self._match(rect_left, rect_right))
            status = np.where(np.isfinite(disparity), np.uint8(UNVERIFIED), np.uint8(NO_MATCH))
            decoded = float("nan")
            counts: dict[str, int] = {}
            cloud = self._triangulate(rect_left, disparity, status)
        else:
            left_code, right_code = self._decode(rect_left, rect_right)
            raw, searched = self._match(rect_left, rect_right)
            # the left's coded region in the second thread while this one converts SGBM's output
            pool = self._second_thread()
            region = pool.submit(_coded_region, left_code) if pool is not None else None
            disparity, edge = disparity_px(raw, searched)
            coded, decoded = region.result() if region is not None else _coded_region(left_code)
            disparity, status, counts, cloud = self._verify_and_triangulate(
                rect_left, disparity, left_code, right_code, coded
            )
        points, colors, verified = cloud
        return FrameCloud(
            disparity=disparity,
            valid=status >= UNVERIFIED,
            points=points,
            colors=colors,
            verified=verified,
            status=status,
            counts=counts,
            decoded_fraction=decoded,
            edge_fraction=edge,
        )
