"""Stereo inputs other than a session: one image pair, a folder of pairs (named as
:data:`vbfe.calib.pairs.PAIR_NAMING` says, as for ``calibrate``), and the calibration of an
already-rectified pair.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from vbfe.acquire.image_size import size_mismatch
from vbfe.calib.calibration import Calibration
from vbfe.calib.importers import import_calibration
from vbfe.calib.pairs import PAIR_NAMING, pair_files
from vbfe.common.errors import CalibrationError, ReconError


class StereoImages(NamedTuple):
    """One raw stereo pair (BGR ``uint8``), shaped like a session frame's ``left``/``right``."""

    left: np.ndarray
    right: np.ndarray


@dataclass(frozen=True)
class ImagePairs:
    """Stereo pairs stored as image files, in name order."""

    lefts: tuple[Path, ...]
    rights: tuple[Path, ...]
    names: tuple[str, ...]

    @property
    def n_frames(self) -> int:
        """Number of pairs."""
        return len(self.names)

    def frame(self, i: int) -> StereoImages:
        """Pair ``i`` read as BGR ``uint8`` (grey images are expanded to three channels)."""
        return StereoImages(_read(self.lefts[i]), _read(self.rights[i]))

    def frame_size(self) -> tuple[int, int]:
        """``(width, height)`` of the first left image."""
        image = _read(self.lefts[0])
        return image.shape[1], image.shape[0]

    def fingerprint(self) -> str:
        """SHA-256 (hex) of all image files, in order."""
        digest = hashlib.sha256()
        for path in (*self.lefts, *self.rights):
            digest.update(path.read_bytes())
        return digest.hexdigest()


def _read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ReconError(f"cannot read image {path}; is it a PNG/JPEG/TIFF image file?")
    return image


def _paired(folder: Path, lefts: dict[str, Path], rights: dict[str, Path]) -> ImagePairs:
    unpaired = sorted(set(lefts) ^ set(rights))
    if unpaired:
        raise ReconError(
            f"{folder}: images without their other eye: {', '.join(unpaired)}; "
            f"every left image needs a right one of the same name"
        )
    names = tuple(sorted(lefts))
    return ImagePairs(tuple(lefts[n] for n in names), tuple(rights[n] for n in names), names)


def find_pairs(folder: str | Path) -> ImagePairs:
    """The stereo pairs in ``folder`` under :data:`~vbfe.calib.pairs.PAIR_NAMING`."""
    folder = Path(folder)
    found = pair_files(folder)
    if found is None:
        raise ReconError(f"{folder} holds no stereo pairs; {PAIR_NAMING}")
    return _paired(folder, found.left, found.right)


def image_pairs(paths: list[str | Path]) -> ImagePairs:
    """Pairs from two image files (left, right) or one folder of pairs."""
    files = [Path(p) for p in paths]
    missing = [str(p) for p in files if not p.exists()]
    if missing:
        raise ReconError(f"{', '.join(missing)} does not exist")
    if len(files) == 1 and files[0].is_dir():
        return find_pairs(files[0])
    if len(files) == 2 and all(p.is_file() for p in files):
        return ImagePairs((files[0],), (files[1],), (files[0].stem,))
    raise ReconError("give a session (.h5), two image files (LEFT RIGHT) or one folder of pairs")


def rectified_calibration(
    fx_px: float,
    fy_px: float,
    baseline_mm: float,
    cx: float,
    cy: float,
    image_size: tuple[int, int],
    doffs_px: float = 0.0,
) -> Calibration:
    """:meth:`Calibration.rectified` from the ``--rectified`` options (baseline in mm), its
    refusal as a ReconError."""
    try:
        return Calibration.rectified(
            fx_px,
            fy_px,
            baseline_mm * 1e-3,
            cx,
            cy,
            image_size,
            doffs_px,
            source="already-rectified pair (--rectified)",
        )
    except CalibrationError as exc:
        raise ReconError(f"--rectified: {exc}") from None


def middlebury_calibration(path: str | Path, image_size: tuple[int, int]) -> Calibration:
    """The rectified geometry in a Middlebury ``calib.txt`` (read by
    :func:`vbfe.calib.importers.import_calibration`) for images of ``image_size``."""
    try:
        calibration, fmt = import_calibration([path])
    except CalibrationError as exc:
        raise ReconError(str(exc)) from None
    if fmt != "middlebury":
        raise ReconError(
            f"{path} is not a Middlebury calib.txt (cam0=[f 0 cx; 0 f cy; 0 0 1], "
            "cam1, doffs, baseline, width, height)"
        )
    mismatch = size_mismatch("the pair has", image_size, str(path), calibration.image_size)
    if mismatch:
        raise ReconError(mismatch)
    return calibration


def pair_calibration(
    image_size: tuple[int, int],
    calib: str | Path | None = None,
    rectified: dict[str, float] | None = None,
) -> Calibration:
    """The calibration of image pairs of ``image_size``: a calibration YAML file, a Middlebury
    ``calib.txt``, or ``rectified`` geometry (the arguments of :func:`rectified_calibration`:
    ``fx_px``, ``fy_px``, ``baseline_mm``, ``cx``, ``cy``, ``doffs_px``)."""
    if rectified is not None:
        if calib is not None:
            raise ReconError(
                "give either a calibration file (--calib) or the rectified "
                "geometry (--rectified), not both"
            )
        return rectified_calibration(image_size=image_size, **rectified)
    if calib is None:
        raise ReconError(
            "image pairs need --calib calib.yaml (or a Middlebury calib.txt), or "
            "--rectified with --f (or --fx and --fy), --baseline, --cx and --cy"
        )
    if Path(calib).suffix.lower() == ".txt":
        return middlebury_calibration(calib, image_size)
    return Calibration.load(calib)
