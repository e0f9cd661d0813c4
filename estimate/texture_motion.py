"""3D surface displacement from the tissue's texture: where the grasped tissue has moved, not
only how far its depth has changed.

A depth-change image sees only the depth component of a pull; a pull 20–50° above the surface
moves the tissue mostly sideways. The tissue's own texture (vessels, mottling) moves with it,
while the projected fringes stay fixed in the projector's frame and slide over it as depth
changes. So the texture is read where the pattern does not reach: per point, the least lit
colour channel over that channel's unlit level in the rest cloud (ambient light times the
albedo: free of the fringes and of the shading). Clouds are laid back on their camera's pixel
grid (a triangulated point's ``x/z, y/z`` is its rectified pixel over ``f``; the grid step is
the rest cloud's median step between neighbours in a row), dense optical flow (OpenCV's DIS)
from the rest texture to the frame's gives every rest pixel's new pixel, and the 3D
displacement there is the frame's point at the new pixel minus the rest point (both point grids
smoothed first: the matcher's depth errors repeat with the fringes). The feature is the largest
magnitude of that field smoothed per component, away from the edges of the view.

For speed (``vbfe live``) a cloud is laid on the grid by a compiled loop (``texture_grid.py``)
with its seen mask as an extra channel, so that each normalised blur is one Gaussian pass. The
point grids and the displacement field, smoothed over several columns anyway, are blurred on a
grid of column pairs (their mean is one part of the Gaussian, the rest is blurred at half the
columns) and read back along the rows at every pixel, by compiled passes that also compare
the frame's points to the rest's and take the peak: on the bench's nine freehand trials the
feature moved by a median 0.05 % (at most 0.56 %) from the full-resolution blurs'.

A cloud without colours (imported depth images) or a plain surface has nothing to track:
:meth:`TextureMotion.from_rest` says why and the feature is NaN.
"""

from __future__ import annotations

import cv2
import numpy as np

from vbfe.estimate.texture_grid import (
    column_pairs,
    grey_image,
    grid_maps,
    peak_magnitude,
    smoothed_points,
    weighted_field,
)

AMBIENT_PERCENTILE = 30  # a channel's unlit level: most of its points lie outside its fringes
CONTRAST_PERCENTILES = (1, 99)  # rest texture range mapped to 0–255 for the flow
TEXTURE_BAND_PX = (2.0, 16.0)  # the texture's contrast: band-pass between these blurs ...
# ... its sd over the mean, at least this (plain bench silicone 0.008–0.011, textured 0.028–0.05)
MIN_TEXTURE_CONTRAST = 0.018
SMOOTH_PX = 6.0  # Gaussian sigma of the displacement field before the peak of its magnitude
BORDER_PX = 20  # the peak is taken this far inside the seen pixels (the flow fails near edges)
POINT_SMOOTH_PX = 6.0  # Gaussian sigma of the point grids before the displacement
FILL_PX = 2.0  # holes of the pixel grid are filled by a normalised blur of this sigma
MAX_GRID_PIXELS = 4_000_000


def _pixels(points: np.ndarray) -> np.ndarray:
    """A cloud's ``(x/z, y/z)``: its rectified pixels over ``f``."""
    return points[:, :2] / points[:, 2:3]


def _blur(image: np.ndarray, sigma_px: float, aspect: float) -> np.ndarray:
    """Gaussian of ``sigma_px`` grid columns, the same length along the rows (``aspect``:
    a column's width over a row's height, 0.5 when rows were averaged in pairs)."""
    return cv2.GaussianBlur(image, (0, 0), sigmaX=sigma_px, sigmaY=max(sigma_px * aspect, 0.3))


def _weighted_blur(values: np.ndarray, sigma_px: float, aspect: float) -> np.ndarray:
    """Blur of channels that hold values (0 where unseen) and, last, their seen mask."""
    return _blur(values, sigma_px, aspect).reshape(values.shape)


def _normalised(values: np.ndarray, floor: float = 1e-6) -> np.ndarray:
    """The value channels of a weighted blur over its weight (the last channel)."""
    return values[..., :-1] / np.maximum(values[..., -1:], floor)


class TextureMotion:
    """Texture tracking against a rest cloud; build it with :meth:`from_rest`."""

    def __init__(
        self, rest_points: np.ndarray, rest_colors: np.ndarray, step: tuple[float, float]
    ) -> None:
        rest = _pixels(rest_points)
        self._step = np.asarray(step, np.float64)  # grid pitch along x and y (in x/z, y/z)
        self._aspect = float(self._step[0] / self._step[1])
        self._lo = rest.min(axis=0) - 2 * self._step
        cols, rows = (np.ceil((rest.max(axis=0) - self._lo) / self._step) + 3).astype(int)
        self._shape = (int(rows), int(cols))
        self._ambient = np.maximum(
            np.percentile(rest_colors, AMBIENT_PERCENTILE, axis=0), 1.0
        ).astype(np.float32)
        rest_xyz, texture = self._maps(rest_points, rest_colors)
        self._rest_xyz = self._smoothed(rest_xyz)
        seen = texture[..., 1] > 0
        self._range = np.percentile(texture[seen, 0], CONTRAST_PERCENTILES)
        filled = self._filled(texture)
        band = _blur(filled, TEXTURE_BAND_PX[0], self._aspect) - _blur(
            filled, TEXTURE_BAND_PX[1], self._aspect
        )
        mean = float(texture[seen, 0].mean()) if seen.any() else 0.0
        self.contrast = float(band[seen].std() / mean) if mean > 0 else 0.0
        self._rest_texture = self._grey(texture)
        self._flow = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        border = (2 * max(1, round(BORDER_PX * self._aspect)) + 1, 2 * BORDER_PX + 1)
        self._border = np.ones(border, np.uint8)

    @classmethod
    def from_rest(
        cls, points: np.ndarray, colors: np.ndarray | None
    ) -> tuple[TextureMotion | None, str]:
        """Tracking against a rest cloud (N×3 m, N×3 colours), or ``None`` and the reason."""
        if colors is None or len(colors) != len(points):
            return None, "the clouds carry no colours"
        points = np.asarray(points, np.float64).reshape(-1, 3)
        finite = np.isfinite(points).all(axis=1) & (points[:, 2] > 0)
        points, colors = points[finite], np.asarray(colors, np.float32)[finite]
        step = pixel_steps(points)
        if not np.isfinite(step).all():
            return None, "the rest cloud is not laid out on a camera's pixel grid"
        span = _pixels(points).max(axis=0) - _pixels(points).min(axis=0)
        if np.prod(span / np.asarray(step) + 5) > MAX_GRID_PIXELS:
            return None, "the rest cloud's pixel grid is too large"
        motion = cls(points, colors, step)
        if not motion.contrast >= MIN_TEXTURE_CONTRAST:
            return None, (
                f"the surface shows no texture to track (contrast {motion.contrast:.3f}"
                f" < {MIN_TEXTURE_CONTRAST})"
            )
        return motion, ""

    def _maps(self, points: np.ndarray, colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points with their seen weight on the grid of column pairs (rows × ⌈cols/2⌉ × 4)
        and texture with its seen mask (rows × cols × 2) on the grid, 0 where unseen."""
        return grid_maps(
            np.ascontiguousarray(points).reshape(-1, 3),
            np.ascontiguousarray(colors, np.float32).reshape(-1, 3),
            self._lo,
            self._step,
            self._ambient,
            self._shape,
        )

    def _smoothed(self, points: np.ndarray) -> np.ndarray:
        """A point grid of column pairs with its seen weight (``_maps``) smoothed by a
        normalised Gaussian of ``POINT_SMOOTH_PX`` (the matcher's depth errors repeat with the
        fringes, a few pixels apart; the pairs' averaging, of variance 1/4 px², is one part of
        it) and read back at every pixel: points and seen mask (rows × cols × 4), NaN and 0
        where under half the neighbourhood is seen."""
        sigma = POINT_SMOOTH_PX
        blurred = cv2.GaussianBlur(
            points,
            (0, 0),
            sigmaX=np.sqrt(sigma * sigma - 0.25) / 2,
            sigmaY=max(sigma * self._aspect, 0.3),
        )
        return smoothed_points(blurred, self._shape)

    def _filled(self, texture: np.ndarray) -> np.ndarray:
        """The texture (``_maps``) with its holes filled from their neighbours (normalised
        Gaussian blur of ``FILL_PX``)."""
        blurred = _normalised(_weighted_blur(texture, FILL_PX, self._aspect))[..., 0]
        return np.where(texture[..., 1] > 0, texture[..., 0], blurred)

    def _grey(self, texture: np.ndarray) -> np.ndarray:
        low, high = self._range
        scale = 255.0 / max(float(high - low), 1e-6)
        blurred = _weighted_blur(texture, FILL_PX, self._aspect)  # fills the holes (_filled)
        return grey_image(texture, blurred, float(low), scale)

    def _weighted_field(self, points: np.ndarray, colors: np.ndarray) -> np.ndarray:
        """3D displacement (m) of every rest pixel with its seen mask (rows × cols × 4, 0 where
        unseen)."""
        points_grid, texture = self._maps(points, colors)
        # OpenCV allocates the flow when given None; its stubs do not say so
        flow = self._flow.calc(self._rest_texture, self._grey(texture), None)  # type: ignore[call-overload]
        return weighted_field(self._smoothed(points_grid), flow, self._rest_xyz)

    def displacement_m(self, points: np.ndarray, colors: np.ndarray) -> np.ndarray:
        """3D displacement (rows × cols × 3, m, NaN where unseen) of every rest pixel."""
        weighted = self._weighted_field(points, colors)
        return np.where(weighted[..., 3:] > 0, weighted[..., :3], np.float32(np.nan))

    def peak_displacement_m(self, points: np.ndarray, colors: np.ndarray | None) -> float:
        """Largest magnitude (m) of a frame's 3D displacement field smoothed per component (a
        Gaussian of ``SMOOTH_PX``) over the pixels at least ``BORDER_PX`` inside what both
        frames see (the flow is unreliable at the edges); NaN without colours or where nothing
        is seen."""
        if colors is None or len(colors) != len(np.asarray(points).reshape(-1, 3)):
            return float("nan")
        weighted = self._weighted_field(points, colors)
        seen = weighted[..., 3] > 0
        inner = cv2.erode(seen.view(np.uint8), self._border).view(bool)
        if not inner.any():
            return float("nan")
        # blurred at half the columns, as the point grids (the pairs' mean is part of it)
        blurred = cv2.GaussianBlur(
            column_pairs(weighted),
            (0, 0),
            sigmaX=np.sqrt(SMOOTH_PX * SMOOTH_PX - 0.25) / 2,
            sigmaY=max(SMOOTH_PX * self._aspect, 0.3),
        )
        return peak_magnitude(blurred, inner)


def pixel_steps(points: np.ndarray) -> tuple[float, float]:
    """The pixel pitch (in ``x/z``, ``y/z``) of a cloud triangulated row by row on a rectified
    pixel grid: along a row the median step between consecutive points, across rows the median
    step from a row's last point to the next row's first (NaN when the points are no grid)."""
    step = np.diff(_pixels(points), axis=0)
    along = step[(step[:, 0] > 0) & (np.abs(step[:, 1]) < 0.25 * step[:, 0]), 0]
    if len(along) < 16:
        return float("nan"), float("nan")
    pitch = float(np.median(along))
    across = step[(step[:, 0] < 0) & (step[:, 1] > 0.5 * pitch), 1]
    return pitch, float(np.median(across)) if len(across) >= 4 else float("nan")
