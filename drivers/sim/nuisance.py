"""What real tissue and optics do to a projected colour pattern, for the simulated bench.

Every effect is off at its default value, so a bench without them renders as before:

- ``subsurface_blur_mm``: light enters tissue, scatters and leaves it blurred by a Gaussian of
  this σ on the surface (a few tenths of a mm in soft tissue); the albedo stays sharp.
- ``specular``, ``specular_shininess``: wet tissue mirrors the light sources (Blinn–Phong lobe
  ``specular · (n·h)^shininess``, no albedo, saturating the sensor): the projector, in its
  pattern's colour, and the endoscope's white light at the tip (at the ambient level). The
  lobes depend on the viewpoint, so the two eyes see highlights in different places.
- ``crosstalk``: the camera's colour filters see the other projector primaries: each camera
  channel receives ``1 - crosstalk`` of its own primary and ``crosstalk / 2`` of each other one.
- ``projector_gamma``: the projector displays ``255 (P / 255) ** gamma`` instead of ``P``.
- ``vignetting``: the lens darkens the image towards its corners, ``1 - v (r / r_corner)²``.
- ``motion_blur_px``, ``motion_blur_deg``: the surface moves this many pixels (in that image
  direction) during the exposure; the bench derives it from the pull speed.

Albedo texture, base colour and ambient light are the bench's ``textured``, ``albedo_bgr`` and
``ambient`` settings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.drivers.sim.optics import refuse_out_of_range, vignette


@dataclass(frozen=True)
class Nuisance:
    """Physically motivated image degradations (all off by default; see the module text).

    Raises:
        DeviceError: a value out of range.
    """

    subsurface_blur_mm: float = 0.0
    specular: float = 0.0
    specular_shininess: float = 100.0
    crosstalk: float = 0.0
    projector_gamma: float = 1.0
    vignetting: float = 0.0
    motion_blur_px: float = 0.0
    motion_blur_deg: float = 0.0

    def __post_init__(self) -> None:
        checks = {
            "subsurface_blur_mm": self.subsurface_blur_mm >= 0,
            "specular": self.specular >= 0,
            "specular_shininess": self.specular_shininess > 0,
            "crosstalk": 0 <= self.crosstalk < 2 / 3,
            "projector_gamma": self.projector_gamma > 0,
            "vignetting": 0 <= self.vignetting < 1,
            "motion_blur_px": self.motion_blur_px >= 0,
        }
        refuse_out_of_range(self, checks, "[bench] nuisance")

    def projector_image(self, pattern: np.ndarray) -> np.ndarray:
        """The pattern as the projector's gamma displays it (``uint8``)."""
        if self.projector_gamma == 1.0:
            return pattern
        lut = np.clip(np.rint(255 * (np.arange(256) / 255) ** self.projector_gamma), 0, 255)
        return cv2.LUT(pattern, lut.astype(np.uint8))

    def surface_light(self, light: np.ndarray, px_per_mm: float) -> np.ndarray:
        """Projected light as the camera records it (before albedo): subsurface blur and colour
        crosstalk of the camera's filters. ``px_per_mm`` is the image scale on the surface."""
        if self.subsurface_blur_mm > 0:
            light = cv2.GaussianBlur(light, (0, 0), self.subsurface_blur_mm * px_per_mm)
        if self.crosstalk > 0:
            c = self.crosstalk
            mixing = np.full((3, 3), c / 2, np.float32)
            np.fill_diagonal(mixing, 1 - c)
            light = cv2.transform(light, mixing)
        return light

    @property
    def affects_camera(self) -> bool:
        """Whether :meth:`camera` changes the image."""
        return self.vignetting > 0 or self.motion_blur_px > 0

    def camera(self, image: np.ndarray) -> np.ndarray:
        """Lens vignetting and motion blur of the image reaching the sensor (``uint8``)."""
        if self.vignetting > 0:
            image = cv2.multiply(
                image, cv2.merge([vignette(image.shape[:2], self.vignetting)] * 3), dtype=cv2.CV_8U
            )
        if self.motion_blur_px > 0:
            image = cv2.filter2D(image, -1, _line_kernel(self.motion_blur_px, self.motion_blur_deg))
        return image


def specular_gain(
    normal: np.ndarray, to_light: np.ndarray, to_eye: np.ndarray, nuisance: Nuisance
) -> np.ndarray:
    """Blinn–Phong highlight strength per pixel (float32) from unit normals and unnormalised
    directions to the light and the eye (H×W×3)."""
    half = to_light / np.linalg.norm(to_light, axis=-1, keepdims=True)
    half += to_eye / np.linalg.norm(to_eye, axis=-1, keepdims=True)
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    cos = np.maximum(np.sum(normal * half, axis=-1), 0)
    return (nuisance.specular * cos**nuisance.specular_shininess).astype(np.float32)


def _line_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    """Normalised box kernel along a line of ``length_px`` (the exposure's motion)."""
    size = int(math.ceil(length_px)) | 1
    kernel = np.zeros((size, size), np.float32)
    centre = size // 2
    dx = 0.5 * length_px * math.cos(math.radians(angle_deg))
    dy = 0.5 * length_px * math.sin(math.radians(angle_deg))
    for t in np.linspace(-1, 1, 4 * size + 1):
        kernel[int(round(centre + t * dy)), int(round(centre + t * dx))] += 1
    return kernel / kernel.sum()
