"""Stereo pairs named in a folder: the one set of naming rules that ``calibrate`` (views) and
``reconstruct`` (image pairs) both follow."""

from __future__ import annotations

import re
from pathlib import Path

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")

PAIR_NAMING = (
    "image pairs are found by name: <name>_left.png + <name>_right.png (also -left/-right, "
    "_L/_R), left<name>.png + right<name>.png (e.g. left01.jpg + right01.jpg; also L01/R01), "
    "subfolders left/ + right/ (or L/ + R/, cam0/ + cam1/) with the same file names"
)

# Each regex names the eye and the pair key of a file stem; tried in this order:
# <name>_left / <name>_right, left<name> / right<name>, <name>_L / <name>_R, L<name> / R<name>
_RULES = (
    re.compile(r"^(?P<key>.+?)[_\-. ]?(?P<eye>left|right)$", re.I),
    re.compile(r"^(?P<eye>left|right)[_\-. ]?(?P<key>.+)$", re.I),
    re.compile(r"^(?P<key>.+?)[_\-. ](?P<eye>l|r)$", re.I),
    re.compile(r"^(?P<eye>l|r)[_\-. ]?(?P<key>\d.*)$", re.I),
)
_FOLDERS = (("left", "right"), ("l", "r"), ("cam0", "cam1"))

Pairs = tuple[dict[str, Path], dict[str, Path]]


def images_in(folder: Path) -> list[Path]:
    """The image files of a folder, sorted by name."""
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def _named(files: list[Path]) -> Pairs | None:
    for pattern in _RULES:
        eyes: dict[str, dict[str, Path]] = {"l": {}, "r": {}}
        for path in files:
            m = pattern.match(path.stem)
            if m:
                eyes[m["eye"][0].lower()][m["key"]] = path
        if eyes["l"] and eyes["r"]:
            return eyes["l"], eyes["r"]
    return None


def _subfolders(folder: Path) -> Pairs | None:
    subdirs = {p.name.lower(): p for p in folder.iterdir() if p.is_dir()}
    for left, right in _FOLDERS:
        if left in subdirs and right in subdirs:
            return (
                {p.stem: p for p in images_in(subdirs[left])},
                {p.stem: p for p in images_in(subdirs[right])},
            )
    return None


def pair_files(folder: str | Path) -> Pairs | None:
    """Left and right image files of a folder by pair name, under the first naming rule of
    :data:`PAIR_NAMING` that labels both eyes; ``None`` when no rule applies. Names present for one
    eye only are for the caller to refuse."""
    folder = Path(folder)
    return _named(images_in(folder)) or _subfolders(folder)
