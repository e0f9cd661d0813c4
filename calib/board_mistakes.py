"""Board options that do not match the printed board, caught on the first views in seconds.

A wrong size or board type makes every detector fail slowly on every view (seconds per image).
:func:`check_board_options` looks quickly at the first few images instead: when the board as
given is seen in none of them, it tries the neighbouring boards on the same images (a
chessboard given by its squares instead of its inner corners, a ChArUco board with its squares
swapped, given by inner corners, with another dictionary or the legacy pattern, the other board
type) and refuses with the one it sees, in the options that describe it. OpenCV's chessboard
detectors find a board either way round, so a chessboard's swapped size is never the mistake.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator, Sequence

import cv2
import numpy as np

from vbfe.calib.board import BoardSpec
from vbfe.calib.chessboard import seen_quickly
from vbfe.common.errors import CalibrationError

logger = logging.getLogger(__name__)

PROBED_VIEWS = 3  # first images looked at before the full detection
# the largest dictionary of each ArUco family: a smaller one of the family holds its first markers
_FAMILIES = ("DICT_4X4", "DICT_5X5", "DICT_6X6", "DICT_7X7")
_FAMILY_SIZES = (50, 100, 250, 1000)
_OTHER_DICTIONARIES = ("DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_36h11")


def _grey(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def _charuco_corners(grey: np.ndarray, spec: BoardSpec) -> int:
    try:
        _, ids, _, _ = cv2.aruco.CharucoDetector(spec.board()).detectBoard(grey)
    except CalibrationError:  # a size the dictionary cannot hold
        return 0
    return 0 if ids is None else len(ids)


def _seen(grey: np.ndarray, spec: BoardSpec, min_corners: int) -> bool:
    """Whether a quick look finds the board in one image (a chessboard whole, a ChArUco board
    with at least ``min_corners`` corners)."""
    if spec.target == "chessboard":
        return seen_quickly(grey, spec.inner_corners)
    return _charuco_corners(grey, spec) >= min(min_corners, spec.n_corners)


def _marker_family(grey: np.ndarray) -> tuple[str, int] | None:
    """The ArUco dictionary family whose markers the image shows most of (its name for
    ``--dictionary``: the smallest of the family holding the highest id seen) and how many."""
    best: tuple[str, int] | None = None
    for family in (*(f"{f}_1000" for f in _FAMILIES), *_OTHER_DICTIONARIES):
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, family))
        _, ids, _ = cv2.aruco.ArucoDetector(dictionary).detectMarkers(grey)
        if ids is None or len(ids) < 2 or (best is not None and len(ids) <= best[1]):
            continue
        name = family
        if family.endswith("_1000"):
            stem = family[: -len("_1000")]
            name = next(f"{stem}_{n}" for n in _FAMILY_SIZES if n > int(ids.max()))
        best = (name, len(ids))
    return best


def _family(dictionary: str) -> str:
    return dictionary.rsplit("_", 1)[0] if dictionary.startswith(_FAMILIES) else dictionary


def _charuco_sizes(nx: int, ny: int) -> list[tuple[int, int]]:
    return list(dict.fromkeys([(nx, ny), (ny, nx), (nx + 1, ny + 1), (ny + 1, nx + 1)]))


def _candidates(spec: BoardSpec, grey: np.ndarray) -> Iterator[tuple[BoardSpec, str]]:
    """The boards next to ``spec`` worth trying on ``grey``, each with the options naming it."""
    replace = dataclasses.replace
    markers = _marker_family(grey)
    if spec.target == "chessboard":
        nx, ny = spec.inner_corners
        if markers is not None:  # a ChArUco board's squares are a chessboard too: say which
            dictionary = markers[0]
            for sx, sy in _charuco_sizes(nx, ny):
                for legacy in (False, True):
                    options = (
                        f"--target charuco --squares-x {sx} --squares-y {sy} --dictionary "
                        f"{dictionary}{' --legacy' if legacy else ''} (and its --marker-mm)"
                    )
                    yield (
                        _charuco(spec, sx, sy, dictionary, legacy),
                        f"it is a ChArUco board, not a chessboard; use {options}",
                    )
        if min(nx, ny) > 3:
            yield (
                replace(spec, squares_x=nx, squares_y=ny),
                f"the board has {nx}x{ny} squares; use --inner-corners {nx - 1}x{ny - 1}",
            )
        return
    sx, sy = spec.squares_x, spec.squares_y
    dictionaries = [spec.dictionary]
    if markers is not None and _family(markers[0]) != _family(spec.dictionary):
        dictionaries.append(markers[0])
    if markers is not None:
        for dictionary in dictionaries:
            for x, y in _charuco_sizes(sx, sy):
                for legacy in (spec.legacy, not spec.legacy):
                    if (x, y, dictionary, legacy) == (sx, sy, spec.dictionary, spec.legacy):
                        continue
                    changed = [f"--squares-x {x} --squares-y {y}"] if (x, y) != (sx, sy) else []
                    if dictionary != spec.dictionary:
                        changed.append(f"--dictionary {dictionary}")
                    if legacy != spec.legacy:
                        changed.append("--legacy" if legacy else "without --legacy")
                    yield _charuco(spec, x, y, dictionary, legacy), f"use {' '.join(changed)}"
        return
    for nx, ny in dict.fromkeys([(sx, sy), (sx - 1, sy - 1)]):
        if min(nx, ny) >= 3:
            yield (
                replace(spec, target="chessboard", squares_x=nx + 1, squares_y=ny + 1),
                f"it is a chessboard, not a ChArUco board; use --target chessboard "
                f"--inner-corners {nx}x{ny}",
            )


def _charuco(spec: BoardSpec, sx: int, sy: int, dictionary: str, legacy: bool) -> BoardSpec:
    marker = spec.marker_m if 0 < spec.marker_m < spec.square_m else 0.7 * spec.square_m
    return dataclasses.replace(
        spec,
        target="charuco",
        squares_x=sx,
        squares_y=sy,
        dictionary=dictionary,
        legacy=legacy,
        marker_m=marker,
    )


def _first(images: Sequence[np.ndarray]) -> str:
    return "the first view" if len(images) == 1 else f"the first {len(images)} views"


def _found_as(spec: BoardSpec) -> str:
    if spec.target == "chessboard":
        nx, ny = spec.inner_corners
        return f"found a chessboard of {nx}x{ny} inner corners"
    return (
        f"found a ChArUco board of {spec.squares_x}x{spec.squares_y} squares ({spec.dictionary}"
        f"{', legacy pattern' if spec.legacy else ''})"
    )


def check_board_options(
    images: Sequence[np.ndarray], spec: BoardSpec, source: str, min_corners: int
) -> None:
    """Look quickly at the first :data:`PROBED_VIEWS` images: when ``spec`` is seen in none of
    them but a neighbouring board is in two of them (one, of a single image), or ArUco markers
    are where a chessboard was given, raise a CalibrationError naming the board seen and the
    options for it. Returns when the board is seen or nothing is (the full detection then
    decides)."""
    if spec.target == "charuco":
        spec.board()  # an unknown dictionary or too small a one is refused as it is
    first = [_grey(image) for image in images[:PROBED_VIEWS]]
    if any(_seen(grey, spec, min_corners) for grey in first):
        return
    needed = min(2, len(first))  # one partly seen view does not make a mistake
    for k, grey in enumerate(first):
        for candidate, advice in _candidates(spec, grey):
            if not _seen(grey, candidate, min_corners):
                continue
            others = sum(_seen(g, candidate, min_corners) for g in first[k + 1 :])
            if 1 + others < needed:
                continue
            raise CalibrationError(
                f"no {spec.describe()} in {_first(first)} of {source}; "
                f"{_found_as(candidate)} in {1 + others} of {len(first)}: {advice}"
            )
    markers = [m for m in map(_marker_family, first) if m is not None]
    family = markers[0][0] if len(markers) >= needed else None
    if family and (spec.target == "chessboard" or _family(family) != _family(spec.dictionary)):
        raise CalibrationError(
            f"no {spec.describe()} in {_first(first)} of {source}; found ArUco "
            f"markers of {family} in {len(markers)} of {len(first)} but no ChArUco board of "
            f"the sizes next to the one given: use --target charuco --dictionary {family} with the "
            "board's own --squares-x/-y (squares, markers included) and --marker-mm"
        )
    logger.info("neither the board as given nor a neighbouring one is seen in the first views")
