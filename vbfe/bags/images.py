"""How images leave vbfe (``--images`` of ``vbfe export`` and the Foxglove server): ``png``
(lossless, ``sensor_msgs/CompressedImage`` format ``png``), ``jpeg[:QUALITY]`` (lossy, default
quality 90) or ``raw`` (uncompressed ``sensor_msgs/Image`` ``bgr8``)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.common.errors import BagError

DEFAULT_JPEG_QUALITY = 90
PNG_LEVEL = 1  # zlib level: the size of level 3 within a few %, at half the time


@dataclass(frozen=True)
class ImageCodec:
    """``kind`` ``png``, ``jpeg`` (with ``quality`` 1-100) or ``raw``."""

    kind: str
    quality: int = DEFAULT_JPEG_QUALITY

    @property
    def compressed(self) -> bool:
        """Whether images go out as ``CompressedImage`` (else as raw ``Image``)."""
        return self.kind != "raw"

    def encode(self, image: np.ndarray) -> bytes:
        """The bytes of a BGR uint8 image in this codec's format (not for ``raw``)."""
        if self.kind == "png":
            ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL])
        else:
            ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            raise BagError(f"OpenCV could not encode a {image.shape} image as {self.kind}")
        return data.tobytes()

    def __str__(self) -> str:
        return f"jpeg:{self.quality}" if self.kind == "jpeg" else self.kind


def image_codec(text: str) -> ImageCodec:
    """``png``, ``jpeg``, ``jpeg:QUALITY`` or ``raw`` as an :class:`ImageCodec`; BagError
    otherwise."""
    kind, _, quality = text.strip().lower().partition(":")
    if kind in ("png", "raw") and not quality:
        return ImageCodec(kind)
    if kind in ("jpeg", "jpg"):
        if not quality:
            return ImageCodec("jpeg")
        if quality.isdigit() and 1 <= int(quality) <= 100:
            return ImageCodec("jpeg", int(quality))
    raise BagError(
        f"--images {text!r}: use png (lossless), jpeg[:QUALITY] with QUALITY 1-100 "
        "(e.g. jpeg:90), or raw"
    )
