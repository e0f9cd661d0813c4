"""Stereo pairs named in a folder: the one set of naming rules that ``calibrate`` (views) and
``reconstruct`` (image pairs) both follow, and the explicit pair lists (OpenCV's stereo_calib
image list, a CSV of pairs)."""

from __future__ import annotations

import csv
import re
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import cv2

from vbfe.common.errors import CalibrationError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
LIST_SUFFIXES = (".xml", ".yaml", ".yml")  # OpenCV FileStorage image lists (stereo_calib)
STAMP_TOLERANCE_MS = 5.0  # Kalibr cam0/cam1: stamps further apart than this do not pair

PAIR_NAMING = (
    "image pairs are found by name: <name>_left.png + <name>_right.png (also -left/-right, "
    "_L/_R), left<name>.png + right<name>.png (e.g. left01.jpg + right01.jpg, ROS "
    "camera_calibration's left-0000.png + right-0000.png; also L01/R01), subfolders left/ + "
    "right/ (or L/ + R/) with the same file names or eye-named ones (left/left01.png + "
    "right/right01.png), Kalibr's cam0/ + cam1/ with nanosecond-stamped names (paired by "
    "nearest stamp), or an OpenCV stereo_calib image list (.xml/.yaml, left and right names "
    "in turn)"
)

# Each regex names the eye and the pair key of a file stem; tried in this order:
# <name>_left / <name>_right, left<name> / right<name>, <name>_L / <name>_R, L<name> / R<name>
_RULES = (
    ("<name>_left/<name>_right", re.compile(r"^(?P<key>.+?)[_\-. ]?(?P<eye>left|right)$", re.I)),
    ("left<name>/right<name>", re.compile(r"^(?P<eye>left|right)[_\-. ]?(?P<key>.+)$", re.I)),
    ("<name>_L/<name>_R", re.compile(r"^(?P<key>.+?)[_\-. ](?P<eye>l|r)$", re.I)),
    ("L<name>/R<name>", re.compile(r"^(?P<eye>l|r)[_\-. ]?(?P<key>\d.*)$", re.I)),
)
_FOLDERS = (("left", "right"), ("l", "r"), ("cam0", "cam1"))
_STAMP = re.compile(r"^\d{9,}$")  # a nanosecond time stamp (Kalibr's bagextractor names)
_SHOWN = 4  # unmatched names shown per eye when nothing pairs


@dataclass
class Pairing:
    """Left and right files by pair name under one rule; names of one eye only are for the
    caller to refuse, except ``unpaired`` (stamps without a partner), which are left out."""

    rule: str
    left: dict[str, Path]
    right: dict[str, Path]
    unpaired: list[str] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        """The pair names both eyes have, sorted."""
        return sorted(set(self.left) & set(self.right))

    @property
    def one_eye(self) -> list[str]:
        """Names only one eye has."""
        return sorted(set(self.left) ^ set(self.right))


def images_in(folder: Path, ext: str | None = None) -> list[Path]:
    """The image files of a folder, sorted by name (only ``ext``, e.g. ``png``, when given);
    two files with one stem and different extensions are a CalibrationError naming them."""
    files = sorted(
        p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
    )
    if ext is not None:
        wanted = "." + ext.lower().lstrip(".")
        return [p for p in files if p.suffix.lower() == wanted]
    stems: dict[str, list[Path]] = defaultdict(list)
    for path in files:
        stems[path.stem].append(path)
    clashes = [paths for paths in stems.values() if len(paths) > 1]
    if clashes:
        shown = "; ".join(" and ".join(p.name for p in paths) for paths in clashes[:3])
        more = f" (and {len(clashes) - 3} more)" if len(clashes) > 3 else ""
        raise CalibrationError(
            f"{folder}: {shown}{more} have the same name and different extensions; keep one "
            f"of each or choose with --ext (e.g. --ext {clashes[0][-1].suffix.lstrip('.')})"
        )
    return files


def _keyed(files: list[Path], rule: re.Pattern[str]) -> Pairing | None:
    eyes: dict[str, dict[str, Path]] = {"l": {}, "r": {}}
    for path in files:
        m = rule.match(path.stem)
        if m:
            eyes[m["eye"][0].lower()][m["key"]] = path
    return Pairing("", eyes["l"], eyes["r"]) if eyes["l"] and eyes["r"] else None


def _candidates(folder: Path, ext: str | None) -> list[Pairing]:
    """Every way a naming rule labels both eyes' files of ``folder``."""
    found = []
    files = images_in(folder, ext)
    for name, rule in _RULES:
        pairing = _keyed(files, rule)
        if pairing is not None:
            pairing.rule = name
            found.append(pairing)
    subdirs = {p.name.lower(): p for p in folder.iterdir() if p.is_dir()}
    for left_dir, right_dir in _FOLDERS:
        if left_dir not in subdirs or right_dir not in subdirs:
            continue
        lefts, rights = images_in(subdirs[left_dir], ext), images_in(subdirs[right_dir], ext)
        where = f"{left_dir}/ + {right_dir}/"
        if lefts and rights and all(_STAMP.match(p.stem) for p in (*lefts, *rights)):
            found.append(_by_stamp(lefts, rights, where))
            continue
        found.append(
            Pairing(f"{where} same names", {p.stem: p for p in lefts}, {p.stem: p for p in rights})
        )
        for name, rule in _RULES:  # eye-named files in eye folders: left/left01 + right/right01
            pairing = _keyed([*lefts, *rights], rule)
            if (
                pairing is not None
                and set(pairing.left.values()) == set(lefts)
                and set(pairing.right.values()) == set(rights)
            ):
                pairing.rule = f"{where} {name}"
                found.append(pairing)
    return found


def _by_stamp(lefts: list[Path], rights: list[Path], where: str) -> Pairing:
    """Kalibr's cam0/cam1: each left stamp paired with the nearest right one when both are each
    other's nearest and within :data:`STAMP_TOLERANCE_MS`; the others listed as unpaired."""
    left_ns = sorted((int(p.stem), p) for p in lefts)
    right_ns = sorted((int(p.stem), p) for p in rights)

    def nearest(t: int, others: list[tuple[int, Path]]) -> tuple[int, Path]:
        return min(others, key=lambda o: abs(o[0] - t))

    pairing = Pairing(f"{where} nearest time stamp", {}, {})
    used = set()
    for t, path in left_ns:
        t_r, right = nearest(t, right_ns)
        if abs(t_r - t) <= STAMP_TOLERANCE_MS * 1e6 and nearest(t_r, left_ns)[0] == t:
            pairing.left[path.stem] = path
            pairing.right[path.stem] = right
            used.add(right)
        else:
            pairing.unpaired.append(f"{path.parent.name}/{path.name}")
    pairing.unpaired += [f"{p.parent.name}/{p.name}" for _, p in right_ns if p not in used]
    return pairing


def pair_files(folder: str | Path, ext: str | None = None) -> Pairing | None:
    """The pairing of a folder's files under the rule of :data:`PAIR_NAMING` that pairs most
    of them (``None`` when no rule labels both eyes); when rules label files but none pairs,
    a CalibrationError names the rule that came closest and shows unmatched names."""
    folder = Path(folder)
    listed = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in LIST_SUFFIXES]
    lists = [p for p in listed if _image_list(p) is not None]
    if len(lists) == 1:
        return list_pairs(lists[0])
    candidates = _candidates(folder, ext)
    if not candidates:
        return None
    best = max(candidates, key=lambda c: (len(c.names), -len(c.one_eye)))
    if best.names:
        return best
    closest = max(candidates, key=lambda c: min(len(c.left), len(c.right)))
    side = [
        f"{a.name} | {b.name}"
        for a, b in zip(
            sorted(closest.left.values())[:_SHOWN],
            sorted(closest.right.values())[:_SHOWN],
            strict=False,
        )
    ]
    raise CalibrationError(
        f"{folder}: no left image pairs with a right one; the closest rule, {closest.rule}, "
        f"found {len(closest.left)} left and {len(closest.right)} right images but no common "
        f"names (left | right: {'; '.join(side)}); rename them to one rule or list the pairs "
        "(calibrate: --pairs FILE.csv); " + PAIR_NAMING
    )


def _image_list(path: Path) -> list[str] | None:
    """The names an OpenCV FileStorage image list holds (its first top-level sequence of
    strings, as stereo_calib reads it), or ``None`` when the file is not one."""
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error:
        return None
    try:
        node = fs.getFirstTopLevelNode() if fs.isOpened() else None
        if node is None or not node.isSeq() or node.size() == 0:
            return None
        names = [node.at(i).string() for i in range(node.size())]
        return names if all(names) else None
    finally:
        fs.release()


def _resolve(base: Path, name: str, source: Path) -> Path:
    path = Path(name) if Path(name).is_absolute() else base / name
    if not path.is_file():
        raise CalibrationError(f"{source} names {name}, which is not a file in {base}")
    return path


def _listed(rule: str, pairs: list[tuple[Path, Path]]) -> Pairing:
    stems = [left.stem for left, _ in pairs]
    keys = stems if len(set(stems)) == len(stems) else [f"{i:04d}" for i in range(len(pairs))]
    return Pairing(
        rule,
        {k: left for k, (left, _) in zip(keys, pairs, strict=True)},
        {k: right for k, (_, right) in zip(keys, pairs, strict=True)},
    )


def list_pairs(path: str | Path) -> Pairing:
    """The pairs of an OpenCV stereo_calib image list (left and right names in turn, relative
    to the list's folder)."""
    path = Path(path)
    names = _image_list(path)
    if names is None or len(names) % 2:
        raise CalibrationError(
            f"{path} is not an OpenCV image list of left and right names in turn "
            f"({'an odd number of names' if names else 'no sequence of file names'})"
        )
    files = [_resolve(path.parent, n, path) for n in names]
    return _listed(f"image list {path.name}", list(zip(files[::2], files[1::2], strict=True)))


def csv_pairs(path: str | Path) -> Pairing:
    """The pairs of a CSV file: one ``left,right`` pair of image paths per line (relative to
    the file's folder; a first line naming no files is a header)."""
    path = Path(path)
    try:
        rows = [r for r in csv.reader(path.read_text(encoding="utf-8").splitlines()) if r]
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"--pairs {path} cannot be read ({exc}); give a CSV file") from None
    if rows and not (path.parent / rows[0][0].strip()).is_file():
        rows = rows[1:]  # header
    bad = [i + 1 for i, r in enumerate(rows) if len(r) != 2]
    if not rows or bad:
        raise CalibrationError(
            f"--pairs {path}: give one 'left,right' pair of image paths per line"
            + (f" (line {bad[0]} has {len(rows[bad[0] - 1])} fields)" if bad else "")
        )
    return _listed(
        f"--pairs {path.name}",
        [
            (_resolve(path.parent, a.strip(), path), _resolve(path.parent, b.strip(), path))
            for a, b in rows
        ],
    )
