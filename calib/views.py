"""Calibration views: left/right image pairs read from a folder (common namings recognised),
from two globs or from a session; single-camera image sets."""

from __future__ import annotations

import glob
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from vbfe.calib.pairs import (
    IMAGE_SUFFIXES,
    LIST_SUFFIXES,
    PAIR_NAMING,
    Pairing,
    csv_pairs,
    images_in,
    list_pairs,
    pair_files,
)
from vbfe.common.errors import CalibrationError

NAMING_RULES = (
    PAIR_NAMING + ", --pairs FILE.csv (one left,right line per pair), or one side-by-side image "
    "per view (left half = left eye)"
)


@dataclass
class ViewSet:
    """Named stereo image pairs (BGR ``uint8``) and where they came from."""

    pairs: list[tuple[np.ndarray, np.ndarray]]
    names: list[str]
    source: str
    unpaired: list[str] = field(default_factory=list)  # files of one eye only, left out

    def __len__(self) -> int:
        return len(self.pairs)


def _read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise CalibrationError(f"cannot read image {path}; is it a valid image file?")
    return image


def _paired(where: Path | str, pairing: Pairing) -> tuple[list[Path], list[Path], list[str]]:
    """The paired files of ``pairing``; names only one eye has are refused."""
    if pairing.one_eye:
        raise CalibrationError(
            f"{where}: views without their other eye: {', '.join(pairing.one_eye)}; {NAMING_RULES}"
        )
    names = pairing.names
    return [pairing.left[n] for n in names], [pairing.right[n] for n in names], names


def _glob(pattern: str) -> list[Path]:
    return sorted(Path(p) for p in glob.glob(pattern) if Path(p).suffix.lower() in IMAGE_SUFFIXES)


def _glob_pairs(left_glob: str, right_glob: str) -> tuple[list[Path], list[Path], list[str]]:
    lefts, rights = _glob(left_glob), _glob(right_glob)
    if not lefts or len(lefts) != len(rights):
        raise CalibrationError(
            f"--left {left_glob!r} matches {len(lefts)} images and --right "
            f"{right_glob!r} {len(rights)}; they must match the same number "
            "(pairs are taken in sorted order)"
        )
    return lefts, rights, [p.stem for p in lefts]


def _split_side_by_side(image: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray]:
    if image.shape[1] % 2:
        raise CalibrationError(
            f"{path} is {image.shape[1]} px wide, so it is not a side-by-side "
            f"pair (width must be even); {NAMING_RULES}"
        )
    half = image.shape[1] // 2
    return image[:, :half], image[:, half:]


def _swapped(views: ViewSet, swap_eyes: bool) -> ViewSet:
    if swap_eyes:
        views.pairs = [(right, left) for left, right in views.pairs]
        views.source += " (eyes swapped)"
    return views


def load_views(
    path: str | Path | None = None,
    every: int = 1,
    left_glob: str | None = None,
    right_glob: str | None = None,
    ext: str | None = None,
    pairs_file: str | Path | None = None,
    swap_eyes: bool = False,
) -> ViewSet:
    """Pairs from a folder (naming rules: :data:`NAMING_RULES`; only files ending in ``ext``
    when given), an OpenCV image list file, a CSV of pairs (``pairs_file``), ``left_glob`` /
    ``right_glob`` (paired in sorted order) or a recorded session (``.h5``, every ``every``-th
    frame); ``swap_eyes`` exchanges the eyes of every pair."""
    if left_glob is not None or right_glob is not None:
        if left_glob is None or right_glob is None:
            raise CalibrationError("give both --left GLOB and --right GLOB")
        lefts, rights, names = _glob_pairs(left_glob, right_glob)
        pairs = [(_read(a), _read(b)) for a, b in zip(lefts, rights, strict=False)]
        return _swapped(
            ViewSet(pairs, names, f"--left {left_glob} --right {right_glob}"), swap_eyes
        )
    if pairs_file is not None:
        lefts, rights, names = _paired(pairs_file, csv_pairs(pairs_file))
        pairs = [(_read(a), _read(b)) for a, b in zip(lefts, rights, strict=True)]
        return _swapped(ViewSet(pairs, names, f"--pairs {pairs_file}"), swap_eyes)
    if path is None:
        raise CalibrationError(
            "give a folder of image pairs, a session, --pairs FILE.csv or --left/--right globs"
        )
    path = Path(path)
    if not path.exists():
        raise CalibrationError(f"{path} does not exist; give a folder of image pairs or a session")
    unpaired: list[str] = []
    if path.is_dir() or path.suffix.lower() in LIST_SUFFIXES:
        pairing = pair_files(path, ext) if path.is_dir() else list_pairs(path)
        if pairing is not None:
            lefts, rights, names = _paired(path, pairing)
            unpaired = pairing.unpaired
            pairs = [(_read(a), _read(b)) for a, b in zip(lefts, rights, strict=True)]
        else:
            files = images_in(path, ext)
            pairs = [_split_side_by_side(_read(f), f) for f in files]
            names = [f.stem for f in files]
    else:
        from vbfe.acquire import SessionReader

        with SessionReader(path) as reader:
            pairs, names = [], []
            for i, frame in enumerate(reader.iter_frames()):
                if i % every == 0:
                    pairs.append((frame.left, frame.right))
                    names.append(f"frame{i:05d}")
    if not pairs:
        raise CalibrationError(
            f"{path} holds no image pairs; capture some with "
            f"'vbfe calibrate capture' ({NAMING_RULES})"
        )
    return _swapped(ViewSet(pairs, names, str(path), unpaired), swap_eyes)


@dataclass
class ImageSet:
    """Named images (BGR ``uint8``) of one camera and where they came from."""

    images: list[np.ndarray]
    names: list[str]
    source: str

    def __len__(self) -> int:
        return len(self.images)


def load_images(
    source: str | Path, eye: str | None = None, every: int = 1, ext: str | None = None
) -> ImageSet:
    """One camera's images: every image of a folder or of a glob pattern, or with ``eye``
    (``left``/``right``) that eye of stereo views (any :func:`load_views` source; a session
    defaults to the left eye); only files ending in ``ext`` when given."""
    source_text = str(source)
    path = Path(source)
    if eye is None and not any(c in source_text for c in "*?[") and path.is_file():
        eye = "left"  # a session
    if eye is not None:
        if eye not in ("left", "right"):
            raise CalibrationError(f"--eye {eye!r}: use left or right")
        views = load_views(path, every, ext=ext)
        k = 0 if eye == "left" else 1
        return ImageSet(
            [pair[k] for pair in views.pairs], views.names, f"{views.source} ({eye} eye)"
        )
    if path.is_dir():
        if pair_files(path, ext) is not None:
            raise CalibrationError(
                f"{path} holds stereo image pairs; say which camera with --eye left or --eye right"
            )
        files = images_in(path, ext)
    elif any(c in source_text for c in "*?["):
        files = _glob(source_text)
    else:
        raise CalibrationError(
            f"{path} does not exist; give a folder of images, a glob such "
            "as 'views/*.png' or a session"
        )
    if not files:
        raise CalibrationError(f"{source_text} holds no images ({', '.join(IMAGE_SUFFIXES)})")
    return ImageSet([_read(f) for f in files], [f.stem for f in files], source_text)


def save_views(
    folder: str | Path, pairs: Sequence[tuple[np.ndarray, np.ndarray]], names: Sequence[str]
) -> list[str]:
    """Write pairs as ``<name>_left.png`` / ``<name>_right.png``; returns the names."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for (left, right), name in zip(pairs, names, strict=False):
        for eye, image in (("left", left), ("right", right)):
            target = folder / f"{name}_{eye}.png"
            if not cv2.imwrite(str(target), image):
                raise CalibrationError(f"cannot write {target}; check the folder is writable")
    return list(names)


def check_sizes(views: ViewSet) -> tuple[int, int]:
    """The common (width, height) of all images; mixed sizes are an error naming the odd views."""
    return _common_size(
        [[(img.shape[1], img.shape[0]) for img in pair] for pair in views.pairs],
        views.names,
        views.source,
    )


def image_size(images: ImageSet) -> tuple[int, int]:
    """The common (width, height) of a camera's images; mixed sizes are an error."""
    return _common_size(
        [[(img.shape[1], img.shape[0])] for img in images.images], images.names, images.source
    )


def _common_size(
    sizes: list[list[tuple[int, int]]], names: list[str], source: str
) -> tuple[int, int]:
    values, counts = np.unique(
        np.array([s for view in sizes for s in view]), axis=0, return_counts=True
    )
    if len(values) > 1:
        common = tuple(int(v) for v in values[np.argmax(counts)])
        odd = [
            f"{name} ({', '.join(f'{w}x{h}' for w, h in view)})"
            for name, view in zip(names, sizes, strict=False)
            if any(s != common for s in view)
        ]
        raise CalibrationError(
            f"{source}: mixed image sizes; most views are "
            f"{common[0]}x{common[1]} but {', '.join(odd)} differ; "
            "calibrate one resolution at a time"
        )
    return int(values[0][0]), int(values[0][1])
