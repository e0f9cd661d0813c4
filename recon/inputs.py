"""Stereo inputs other than a session: one image pair, a folder of pairs, and the calibration
of an already-rectified pair.

Folder naming (any of): ``<name>_left.png`` + ``<name>_right.png``; ``left<name>.png`` +
``right<name>.png``; sub-folders ``left/`` and ``right/`` holding files of the same names.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.recon.errors import ReconError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


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


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def _paired(folder: Path, lefts: dict[str, Path], rights: dict[str, Path]) -> ImagePairs:
    unpaired = sorted(set(lefts) ^ set(rights))
    if unpaired:
        raise ReconError(f"{folder}: images without their other eye: {', '.join(unpaired)}; "
                         f"every left image needs a right one of the same name")
    names = tuple(sorted(lefts))
    return ImagePairs(tuple(lefts[n] for n in names), tuple(rights[n] for n in names), names)


def _pair_key(stem: str, eye: str) -> str | None:
    """The pair name in a file stem ``<name>_<eye>`` or ``<eye><name>``; None for other files."""
    if stem.lower().endswith("_" + eye):
        return stem[:-len(eye) - 1]
    if stem.lower().startswith(eye):
        return stem[len(eye):]
    return None


def find_pairs(folder: str | Path) -> ImagePairs:
    """The stereo pairs in ``folder`` under any of the module's naming rules."""
    folder = Path(folder)
    files = _images(folder)
    lefts = {k: p for p in files if (k := _pair_key(p.stem, "left")) is not None}
    rights = {k: p for p in files if (k := _pair_key(p.stem, "right")) is not None}
    if not lefts and not rights and (folder / "left").is_dir() and (folder / "right").is_dir():
        lefts = {p.stem: p for p in _images(folder / "left")}
        rights = {p.stem: p for p in _images(folder / "right")}
    if not lefts and not rights:
        raise ReconError(f"{folder} holds no stereo pairs; name them <name>_left.png and "
                         f"<name>_right.png, left<name>.png and right<name>.png, or put them in "
                         f"left/ and right/ sub-folders")
    return _paired(folder, lefts, rights)


def image_pairs(paths: list[str | Path]) -> ImagePairs:
    """Pairs from two image files (left, right) or one folder of pairs."""
    paths = [Path(p) for p in paths]
    missing = [str(p) for p in paths if not p.exists()]
    if missing:
        raise ReconError(f"{', '.join(missing)} does not exist")
    if len(paths) == 1 and paths[0].is_dir():
        return find_pairs(paths[0])
    if len(paths) == 2 and all(p.is_file() for p in paths):
        return ImagePairs((paths[0],), (paths[1],), (paths[0].stem,))
    raise ReconError("give a session (.h5), two image files (LEFT RIGHT) or one folder of pairs")


def rectified_calibration(f_px: float, baseline_mm: float, cx: float, cy: float,
                          image_size: tuple[int, int], doffs_px: float = 0.0) -> Calibration:
    """Calibration of an already-rectified, distortion-free pair: focal length ``f_px``,
    baseline ``baseline_mm`` (left camera on the left) and the left principal point ``cx, cy``
    (px) of images of ``image_size`` (width, height). ``doffs_px`` is the right principal
    point's x minus the left's (Middlebury's ``doffs``; ``z = f·B / (d + doffs)``)."""
    width, height = image_size
    problems = []
    if not f_px > 0:
        problems.append(f"focal length --f must be positive (got {f_px})")
    if not baseline_mm > 0:
        problems.append(f"--baseline must be positive (got {baseline_mm} mm)")
    if not (0 <= cx < width and 0 <= cy < height):
        problems.append(f"principal point ({cx}, {cy}) lies outside the {width}x{height} image")
    if problems:
        raise ReconError("; ".join(problems))
    if not math.isfinite(doffs_px) or not 0 <= cx + doffs_px < width:
        raise ReconError(f"--doffs {doffs_px} puts the right principal point ({cx + doffs_px}) "
                         f"outside the {width}-px wide image")
    K = np.array([[f_px, 0.0, cx], [0.0, f_px, cy], [0.0, 0.0, 1.0]])
    K2 = K.copy()
    K2[0, 2] = cx + doffs_px
    baseline_m = baseline_mm * 1e-3
    P1 = np.hstack([K, np.zeros((3, 1))])
    P2 = np.hstack([K2, np.zeros((3, 1))])
    P2[0, 3] = -f_px * baseline_m
    # OpenCV's Q: [0, 0, -1/Tx, (cx - cx')/Tx] with Tx = -B
    Q = np.array([[1.0, 0.0, 0.0, -cx], [0.0, 1.0, 0.0, -cy], [0.0, 0.0, 0.0, f_px],
                  [0.0, 0.0, 1.0 / baseline_m, doffs_px / baseline_m]])
    return Calibration(K1=K, D1=np.zeros(5), K2=K2, D2=np.zeros(5), R=np.eye(3),
                       T=np.array([-baseline_m, 0.0, 0.0]), R1=np.eye(3), R2=np.eye(3), P1=P1,
                       P2=P2, Q=Q, image_size=(width, height),
                       info={"source": "already-rectified pair (--rectified)"})


def middlebury_calibration(path: str | Path, image_size: tuple[int, int]) -> Calibration:
    """The rectified geometry in a Middlebury ``calib.txt`` (``cam0=[f 0 cx; 0 f cy; 0 0 1]``,
    ``cam1``, ``doffs``, ``baseline`` in mm) for images of ``image_size``."""
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ReconError(f"cannot read Middlebury calibration {path}: {exc}") from None
    fields = dict(re.findall(r"^\s*(\w+)\s*=\s*(.+?)\s*$", text, re.MULTILINE))
    try:
        cam0 = np.array([float(v) for v in re.findall(r"[-+\d.eE]+", fields["cam0"])])
        f_px, cx, cy = cam0[0], cam0[2], cam0[5]
        baseline_mm, doffs = float(fields["baseline"]), float(fields.get("doffs", 0.0))
    except (KeyError, IndexError, ValueError):
        raise ReconError(f"{path} is not a Middlebury calib.txt (needs cam0=[f 0 cx; 0 f cy; "
                         f"0 0 1], baseline= and doffs=)") from None
    calibration = rectified_calibration(f_px, baseline_mm, cx, cy, image_size, doffs)
    return calibration.replace(info={"source": f"Middlebury calibration {path}"})


def pair_calibration(image_size: tuple[int, int], calib: str | Path | None = None,
                     rectified: dict[str, float] | None = None) -> Calibration:
    """The calibration of image pairs of ``image_size``: a calibration YAML file, a Middlebury
    ``calib.txt``, or ``rectified`` geometry (the arguments of :func:`rectified_calibration`:
    ``f_px``, ``baseline_mm``, ``cx``, ``cy``, ``doffs_px``)."""
    if rectified is not None:
        if calib is not None:
            raise ReconError("give either a calibration file (--calib) or the rectified "
                             "geometry (--rectified), not both")
        return rectified_calibration(image_size=image_size, **rectified)
    if calib is None:
        raise ReconError("image pairs need --calib calib.yaml (or a Middlebury calib.txt), or "
                         "--rectified with --f, --baseline, --cx and --cy")
    if Path(calib).suffix.lower() == ".txt":
        return middlebury_calibration(calib, image_size)
    return Calibration.load(calib)
