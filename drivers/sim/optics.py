"""An endoscope camera's optics and sensor as its images show them, for the simulated bench's
board views: soft focus, lens vignetting, a dim exposure, sensor noise and compression.

Applied in the order light meets them: the lens blurs (``defocus_px``, the σ of a Gaussian
point spread in pixels) and darkens towards the corners (``vignetting``, ``1 - v (r /
r_corner)²``), the exposure scales the light (``exposure``), the sensor adds photon noise (its
variance ``shot_noise`` × the grey level) and read noise (σ ``noise_sigma`` grey levels), the
values are rounded to 8 bits, and the video path may compress them (``jpeg_quality`` 1-100, 0:
none). The defaults are the bench's clean camera: a mild blur and a little read noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.common.settings import parse_table


@dataclass(frozen=True)
class Optics:
    """Image degradations of one camera (see the module text).

    Raises:
        DeviceError: a value out of range.
    """

    defocus_px: float = 0.5
    vignetting: float = 0.0
    exposure: float = 1.0
    shot_noise: float = 0.0
    noise_sigma: float = 1.5
    jpeg_quality: int = 0

    def __post_init__(self) -> None:
        checks = {
            "defocus_px": self.defocus_px >= 0,
            "vignetting": 0 <= self.vignetting < 1,
            "exposure": self.exposure > 0,
            "shot_noise": self.shot_noise >= 0,
            "noise_sigma": self.noise_sigma >= 0,
            "jpeg_quality": 0 <= self.jpeg_quality <= 100,
        }
        refuse_out_of_range(self, checks, "[bench] board_optics")

    @classmethod
    def from_table(cls, table: dict[str, Any] | None) -> Optics:
        """The optics a ``[bench] board_optics`` table describes (absent keys: defaults)."""
        return parse_table(cls, table or {}, "bench.board_optics")

    def image(self, light: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The 8-bit grey image the camera records of ``light`` (float32 grey levels as a
        perfect camera would record them)."""
        grey = light
        if self.defocus_px > 0:
            grey = cv2.GaussianBlur(grey, (0, 0), self.defocus_px)
        if self.vignetting > 0:
            grey = grey * vignette(grey.shape[:2], self.vignetting)
        if self.exposure != 1.0:
            grey = grey * np.float32(self.exposure)
        if self.shot_noise > 0:
            sigma = np.sqrt(np.maximum(grey, 0) * self.shot_noise).astype(np.float32)
            grey = grey + sigma * rng.standard_normal(grey.shape).astype(np.float32)
        grey = grey + rng.normal(0.0, self.noise_sigma, grey.shape).astype(np.float32)
        grey = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
        if self.jpeg_quality:
            ok, encoded = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
            if not ok:
                raise DeviceError("OpenCV could not JPEG-encode a simulated image")
            decoded = cv2.imdecode(encoded, cv2.IMREAD_GRAYSCALE)
            if decoded is None:
                raise DeviceError("OpenCV could not decode a simulated JPEG image")
            grey = decoded
        return grey


def refuse_out_of_range(settings: object, checks: dict[str, bool], what: str) -> None:
    """Raise if any of ``settings``' fields fails its check (``checks``: field name → in range).

    Raises:
        DeviceError: naming ``what`` and each field out of range with its value.
    """
    wrong = [name for name, ok in checks.items() if not ok]
    if wrong:
        raise DeviceError(
            f"{what} out of range: " + ", ".join(f"{n} = {getattr(settings, n)}" for n in wrong)
        )


def vignette(shape: tuple[int, int], strength: float) -> np.ndarray:
    """The lens's relative illumination ``1 - strength (r / r_corner)²`` over an image of
    ``shape`` (height, width; float32)."""
    height, width = shape
    v, u = np.mgrid[0:height, 0:width].astype(np.float32)
    r2 = ((u - (width - 1) / 2) ** 2 + (v - (height - 1) / 2) ** 2) / (
        (width / 2) ** 2 + (height / 2) ** 2
    )
    return 1 - strength * r2
