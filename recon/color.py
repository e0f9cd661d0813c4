"""Colour crosstalk correction after Caspi, Kiryati & Shamir (1998): ``C = A·K·P + C0``.

``P`` is the projected colour (projector primaries), ``K`` the 3×3 camera/projector mixing
matrix, ``A`` the diagonal, per-pixel albedo of the surface and ``C0`` the ambient offset. ``K``
is estimated (rows normalised to sum 1, which fixes the scale shared with ``A``) from captures of
flat red, green, blue, black and white projections; per pixel the albedo cancels in
``(C_j - C_black) / (C_white - C_black)``. In one-shot frames the albedo is removed locally: each
camera channel is divided by its maximum over a few fringes, where a fringe of each primary is
seen at full brightness. All images and vectors are in OpenCV's B, G, R channel order.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.common.errors import ReconError
from vbfe.drivers.camera.base import FrameSource
from vbfe.drivers.projector.base import Projector
from vbfe.recon import kernels

CAPTURE_NAMES = ("blue", "green", "red", "black", "white")  # primaries in B, G, R order
FLAT_BGR = {
    "blue": (255, 0, 0),
    "green": (0, 255, 0),
    "red": (0, 0, 255),
    "black": (0, 0, 0),
    "white": (255, 255, 255),
}
MIN_SIGNAL = 8.0  # grey levels above black for a pixel to take part in the estimate
DARK_FRACTION = 0.25  # local contrast below this share of the image's contrast stays dark
SPAN_PERCENTILE = 99  # the image's contrast: this percentile of the local ranges
SPAN_STEP = 8  # of every n-th row and column


@dataclass(frozen=True)
class ColorModel:
    """Mixing matrix ``mixing`` (camera BGR ← projector BGR) and offset ``offset`` (grey levels)."""

    mixing: np.ndarray
    offset: np.ndarray

    @classmethod
    def identity(cls) -> ColorModel:
        """No crosstalk, no ambient light."""
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_calibration(cls, calibration: Calibration) -> ColorModel:
        """The calibration's ``color_mixing``/``color_offset``, or identity when it has none."""
        if calibration.color_mixing is None:
            return cls.identity()
        offset = calibration.color_offset
        return cls(
            np.asarray(calibration.color_mixing, float).reshape(3, 3),
            np.zeros(3) if offset is None else np.asarray(offset, float).reshape(3),
        )

    def apply_to(self, calibration: Calibration) -> Calibration:
        """A copy of a :class:`vbfe.calib.Calibration` that carries this colour model."""
        return calibration.replace(color_mixing=self.mixing, color_offset=self.offset)

    def correct(self, image: np.ndarray, albedo_window_px: int | None = None) -> np.ndarray:
        """Projected colour per pixel (float32 H×W×3, BGR, ~0..1 where a fringe is brightest).

        With ``albedo_window_px`` the surface colour is removed by normalising each camera
        channel by its local range over that many pixels along the row (~3–4 fringe widths);
        without it the result is in grey levels.
        """
        if not albedo_window_px:
            offset = tuple(float(v) for v in self.offset) + (0.0,)
            # OpenCV takes a scalar (per channel) here; its stubs do not say so
            signal = cv2.subtract(image, offset, dtype=cv2.CV_32F)  # type: ignore[call-overload]
            return cv2.transform(
                np.maximum(signal, 0.0), np.linalg.inv(self.mixing).astype(np.float32)
            )
        normalised = remove_base_color(self._signal(image), int(albedo_window_px))
        unmix = self._albedo_unmix
        return normalised if unmix is None else cv2.transform(normalised, unmix)

    def fringe_colour(
        self, image: np.ndarray, albedo_window_px: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """``max(correct(image, albedo_window_px), 0)`` and its channel sum (float32 H×W): after
        the correction one channel carries a fringe, and the sum is its brightness."""
        value = np.empty(image.shape[:2], np.float32)
        unmix = self._albedo_unmix
        if unmix is None:  # clamped and summed as it is normalised
            return remove_base_color(self._signal(image), int(albedo_window_px), value), value
        colour = self.correct(image, albedo_window_px)
        kernels.clamp_and_sum(colour, value)
        return colour, value

    def _signal(self, image: np.ndarray) -> np.ndarray:
        """The uint8 image less the offset (saturating at 0); without an offset, a copy (or
        the image itself)."""
        offset = tuple(float(v) for v in self.offset) + (0.0,)
        if not any(offset):
            return np.ascontiguousarray(image)
        # OpenCV takes a scalar (per channel) here; its stubs do not say so
        return cv2.subtract(image, offset)  # type: ignore[call-overload]

    @functools.cached_property
    def _albedo_unmix(self) -> np.ndarray | None:
        """The unmixing of albedo-normalised colours (float32 3×3), None without crosstalk (the
        identity, whose product changes no value: normalised colours are finite)."""
        unmix = (np.linalg.inv(self.mixing) * np.diag(self.mixing)).astype(np.float32)
        return None if np.array_equal(unmix, np.eye(3, dtype=np.float32)) else unmix


def color_calibration_patterns(width: int, height: int) -> dict[str, np.ndarray]:
    """The flat projector images to capture for :func:`estimate_color_model` (BGR uint8)."""
    return {name: np.full((height, width, 3), bgr, np.uint8) for name, bgr in FLAT_BGR.items()}


def estimate_color_model(captures: Mapping[str, np.ndarray]) -> ColorModel:
    """Fit ``K`` and ``C0`` from captures named blue, green, red, black and white (BGR images)."""
    missing = [name for name in CAPTURE_NAMES if name not in captures]
    if missing:
        raise ReconError(
            f"colour calibration needs captures of flat {missing} projections; "
            f"project each colour full-screen and capture it"
        )
    black = np.asarray(captures["black"], np.float64).reshape(-1, 3)
    white = np.asarray(captures["white"], np.float64).reshape(-1, 3) - black
    bright = np.all(white > MIN_SIGNAL, axis=1)
    if bright.sum() < 100:
        raise ReconError(
            "colour calibration: the white capture is not brighter than the black "
            "one; check the projector is on and lights the scene"
        )
    columns = []
    for name in CAPTURE_NAMES[:3]:
        response = np.asarray(captures[name], np.float64).reshape(-1, 3) - black
        columns.append(np.median(response[bright] / white[bright], axis=0))
    mixing = np.stack(columns, axis=1)
    mixing /= mixing.sum(axis=1, keepdims=True)
    if abs(np.linalg.det(mixing)) < 1e-3:
        raise ReconError(
            "colour calibration: the red, green and blue captures are not distinct "
            "(mixing matrix is singular); check the projections and exposure"
        )
    return ColorModel(mixing=mixing, offset=np.median(black, axis=0))


def capture_color_model(
    camera: FrameSource,
    projector: Projector,
    frames: int = 3,
    settle_s: float = 0.15,
    timeout_s: float = 2.0,
) -> ColorModel:
    """Fit the colour model from a calibration capture: each flat projection of
    :func:`color_calibration_patterns` is shown, the frames that arrived less than
    ``settle_s`` after the projector reported it are dropped (projector latency and exposure)
    and ``frames`` frames of both eyes are averaged. ``camera`` and ``projector`` are open
    devices aimed at a surface (a white target is best; any albedo cancels)."""
    captures = {}
    for name, image in color_calibration_patterns(projector.width, projector.height).items():
        due_ns = projector.show(image, f"color-{name}").t_host_ns + int(round(settle_s * 1e9))
        views: list[np.ndarray] = []
        while len(views) < frames:
            frame = camera.read_after(due_ns, timeout_s)
            if frame is None:
                raise ReconError(
                    f"colour calibration: no camera frame within {timeout_s} s "
                    f"while projecting flat {name}; check the camera"
                )
            views.append(np.concatenate([frame.left, frame.right], axis=1))
        captures[name] = np.mean(views, axis=0)
    return estimate_color_model(captures)


def remove_base_color(
    signal: np.ndarray, window_px: int, value: np.ndarray | None = None
) -> np.ndarray:
    """Per-channel local contrast normalisation along rows: ``(C - min) / (max - min)``, float32.

    Over ``window_px`` (a few fringe widths) every channel sees both a fringe of its own colour
    at full brightness and a dark fringe boundary, so the local range is the surface's albedo
    times the projector's brightness and the local minimum is the ambient light. Regions whose
    range is small compared with the image's (unlit background, shadows) stay dark. ``signal``
    is a uint8 B, G, R image; min and max are OpenCV's row erode and dilate by ``window_px | 1``
    pixels, each smoothed by its box filter over that many pixels and 3 rows (compiled:
    :func:`vbfe.recon.kernels.local_range`, the same values). With ``value`` (float32 H×W) the
    result is clamped at 0 and ``value`` receives its channel sums.
    """
    signal = np.ascontiguousarray(signal)
    low, high = np.empty_like(signal), np.empty_like(signal)
    kernels.local_range(signal, (window_px | 1) // 2, low, high)
    floor = np.maximum(DARK_FRACTION * _range_percentile(low, high), MIN_SIGNAL).astype(np.float32)
    normalised = np.empty(signal.shape, np.float32)
    kernels.normalise_range(
        signal,
        low,
        high,
        floor,
        normalised,
        value is not None,
        _NO_VALUE if value is None else value,
    )
    return normalised


_NO_VALUE = np.empty((0, 0), np.float32)  # remove_base_color without channel sums


def _range_percentile(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """``np.percentile`` (``SPAN_PERCENTILE``) per channel of ``high - low`` on every
    ``SPAN_STEP``-th row and column (float32, 3): the two order statistics it interpolates
    between are counted (compiled), the interpolation is numpy's own."""
    n = len(range(0, low.shape[0], SPAN_STEP)) * len(range(0, low.shape[1], SPAN_STEP))
    rank = int(np.floor((n - 1) * (SPAN_PERCENTILE / 100)))
    stats = kernels.range_order_statistics(low, high, SPAN_STEP, rank)
    return np.array([_percentile_between(n, rank, int(a), int(b)) for a, b in stats], np.float32)


@functools.lru_cache(maxsize=4096)
def _percentile_between(n: int, rank: int, below: int, above: int) -> np.float32:
    """``np.percentile`` of ``n`` float32 values whose ``rank``-th and next smallest are
    ``below`` and ``above`` (all it depends on)."""
    values = np.full(n, above, np.float32)
    values[: rank + 1] = below
    return np.percentile(values, SPAN_PERCENTILE)
