"""Calibration views: left/right image pairs read from a folder of PNGs or from a session."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vbfe.calib.errors import CalibrationError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass
class ViewSet:
    """Named stereo image pairs (BGR ``uint8``) and where they came from."""

    pairs: list[tuple[np.ndarray, np.ndarray]]
    names: list[str]
    source: str

    def __len__(self) -> int:
        return len(self.pairs)


def _read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise CalibrationError(f"cannot read image {path}; is it a valid image file?")
    return image


def _folder_pairs(folder: Path) -> tuple[list[Path], list[Path], list[str]]:
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    lefts = {p.stem[: -len("_left")]: p for p in files if p.stem.endswith("_left")}
    rights = {p.stem[: -len("_right")]: p for p in files if p.stem.endswith("_right")}
    if not lefts and (folder / "left").is_dir() and (folder / "right").is_dir():
        lefts = {p.stem: p for p in sorted((folder / "left").iterdir())
                 if p.suffix.lower() in IMAGE_SUFFIXES}
        rights = {p.stem: p for p in sorted((folder / "right").iterdir())
                  if p.suffix.lower() in IMAGE_SUFFIXES}
    unpaired = sorted(set(lefts) ^ set(rights))
    if unpaired:
        raise CalibrationError(f"{folder}: views without their other eye: {', '.join(unpaired)}; "
                               "every <name>_left.png needs a <name>_right.png")
    names = sorted(lefts)
    return [lefts[n] for n in names], [rights[n] for n in names], names


def load_views(path: str | Path, every: int = 1) -> ViewSet:
    """Pairs from a folder (``<name>_left.png`` + ``<name>_right.png``, or ``left/`` + ``right/``)
    or from a recorded session (``.h5``, every ``every``-th frame)."""
    path = Path(path)
    if not path.exists():
        raise CalibrationError(f"{path} does not exist; give a folder of image pairs or a session")
    if path.is_dir():
        lefts, rights, names = _folder_pairs(path)
        pairs = [(_read(a), _read(b)) for a, b in zip(lefts, rights)]
    else:
        from vbfe.acquire import SessionReader

        with SessionReader(path) as reader:
            pairs, names = [], []
            for i, frame in enumerate(reader.iter_frames()):
                if i % every == 0:
                    pairs.append((frame.left, frame.right))
                    names.append(f"frame{i:05d}")
    if not pairs:
        raise CalibrationError(f"{path} holds no image pairs; capture some with "
                               "'vbfe calibrate capture'")
    return ViewSet(pairs, names, str(path))


def save_views(folder: str | Path, pairs: Sequence[tuple[np.ndarray, np.ndarray]],
               names: Sequence[str]) -> list[str]:
    """Write pairs as ``<name>_left.png`` / ``<name>_right.png``; returns the names."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for (left, right), name in zip(pairs, names):
        for eye, image in (("left", left), ("right", right)):
            target = folder / f"{name}_{eye}.png"
            if not cv2.imwrite(str(target), image):
                raise CalibrationError(f"cannot write {target}; check the folder is writable")
    return list(names)


def check_sizes(views: ViewSet) -> tuple[int, int]:
    """The common (width, height) of all images; mixed sizes are an error naming the odd views."""
    sizes = [(img.shape[1], img.shape[0]) for pair in views.pairs for img in pair]
    values, counts = np.unique(np.array(sizes), axis=0, return_counts=True)
    if len(values) > 1:
        common = tuple(int(v) for v in values[np.argmax(counts)])
        odd = [f"{name} ({l.shape[1]}x{l.shape[0]}, {r.shape[1]}x{r.shape[0]})"
               for name, (l, r) in zip(views.names, views.pairs)
               if (l.shape[1], l.shape[0]) != common or (r.shape[1], r.shape[0]) != common]
        raise CalibrationError(f"{views.source}: mixed image sizes; most views are "
                               f"{common[0]}x{common[1]} but {', '.join(odd)} differ; "
                               "calibrate one resolution at a time")
    return int(values[0][0]), int(values[0][1])
