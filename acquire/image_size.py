"""The one check that images and their calibration are of one camera mode (size)."""

from __future__ import annotations


def size_mismatch(
    images: str, size: tuple[int, int], calibration: str, calibration_size: tuple[int, int]
) -> str | None:
    """The message naming both sizes when ``size`` (width, height) of ``images`` is not
    ``calibration_size``, else ``None``; each package raises it as its own error."""
    if tuple(size) == tuple(calibration_size):
        return None
    return (
        f"{images} {size[0]}x{size[1]} images but {calibration} is for "
        f"{calibration_size[0]}x{calibration_size[1]}; use the calibration of this camera "
        "mode (or calibrate at this size)"
    )
