"""Calibration targets (ChArUco or plain chessboard): their description, detection and
printable images."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vbfe.calib.chessboard import (
    canonical,
    corner_spacing,
    find_chessboard,
    refine,
    subpix_windows,
)
from vbfe.calib.edge_lines import EDGE_LINES, edge_line_corners
from vbfe.calib.edge_width import edge_width_px, neighbour_pairs
from vbfe.calib.options import calib_field, calib_settings, from_table
from vbfe.common.errors import CalibrationError
from vbfe.common.files import save_figure, write_bytes_atomic

TARGETS = ("charuco", "chessboard")


@dataclass(frozen=True)
class BoardSpec:
    """A calibration target: squares along x and y, square side (metres) and, for ChArUco, the
    marker side and dictionary. A chessboard of ``squares_x`` × ``squares_y`` squares has
    ``(squares_x - 1)`` × ``(squares_y - 1)`` inner corners, all of which must be seen."""

    squares_x: int = calib_field("squares_x")
    squares_y: int = calib_field("squares_y")
    square_m: float = calib_field("square_mm", 1e-3)
    marker_m: float = calib_field("marker_mm", 1e-3)
    dictionary: str = calib_field("dictionary")
    legacy: bool = calib_field("legacy")  # boards generated before OpenCV 4.6
    target: str = calib_field("target")  # "charuco" or "chessboard"

    def __post_init__(self) -> None:
        if self.target not in TARGETS:
            raise CalibrationError(
                f"unknown calibration target {self.target!r} (--target); "
                f"use one of {', '.join(TARGETS)}"
            )
        if self.target == "chessboard":
            if min(self.squares_x, self.squares_y) < 4:
                raise CalibrationError(
                    f"chessboard with {self.squares_x - 1}x{self.squares_y - 1} inner corners "
                    "(--inner-corners): need at least 3 along each side, e.g. 9x6"
                )
        elif min(self.squares_x, self.squares_y) < 3:
            raise CalibrationError(
                f"ChArUco board of {self.squares_x}x{self.squares_y} squares (--squares-x, "
                "--squares-y): need at least 3 along each side, e.g. 9x7"
            )
        if not np.isfinite(self.square_m) or self.square_m <= 0:
            raise CalibrationError(
                f"square size {self.square_m * 1e3:g} mm (--square-mm): must "
                "be a positive length, e.g. 3"
            )
        if self.target == "charuco" and not (np.isfinite(self.marker_m) and self.marker_m > 0):
            raise CalibrationError(
                f"marker size {self.marker_m * 1e3:g} mm (--marker-mm): must "
                "be a positive length, e.g. 2.2 for 3 mm squares"
            )
        if self.target == "charuco" and self.marker_m >= self.square_m:
            raise CalibrationError(
                f"marker size {self.marker_m * 1e3:g} mm (--marker-mm) must be "
                f"smaller than the square size {self.square_m * 1e3:g} mm"
            )

    @classmethod
    def from_config(cls, calib_table: dict[str, Any]) -> BoardSpec:
        """The board of a rig config's ``[calib]`` table (sizes there are in mm; a chessboard
        may be given as ``inner_corners = [9, 6]`` instead of its squares)."""
        inner = calib_settings(calib_table).inner_corners  # checked: a list of integers
        table = {k: v for k, v in calib_table.items() if k != "inner_corners"}
        if inner:
            if len(inner) != 2:
                raise CalibrationError(
                    f"[calib] inner_corners = {inner!r}: give [nx, ny], e.g. [9, 6]"
                )
            table.update(squares_x=int(inner[0]) + 1, squares_y=int(inner[1]) + 1)
        return from_table(cls, table)

    @property
    def inner_corners(self) -> tuple[int, int]:
        """Inner chessboard corners along x and y."""
        return self.squares_x - 1, self.squares_y - 1

    @property
    def name(self) -> str:
        """``ChArUco board`` or ``chessboard``."""
        return "chessboard" if self.target == "chessboard" else "ChArUco board"

    def describe(self) -> str:
        """The target in words, for messages, e.g. ``chessboard, 9x6 inner corners, 3 mm``."""
        if self.target == "chessboard":
            nx, ny = self.inner_corners
            return f"chessboard, {nx}x{ny} inner corners, {self.square_m * 1e3:g} mm squares"
        return (
            f"ChArUco board, {self.squares_x}x{self.squares_y} squares, {self.dictionary}"
            f"{', legacy pattern' if self.legacy else ''}"
        )

    def calib_table(self) -> dict[str, Any]:
        """The ``[calib]`` keys that give this board (what a rig file keeps of it)."""
        table: dict[str, Any] = {"target": self.target, "square_mm": round(self.square_m * 1e3, 9)}
        if self.target == "chessboard":
            return {**table, "inner_corners": list(self.inner_corners)}
        return {
            **table,
            "inner_corners": [],
            "squares_x": self.squares_x,
            "squares_y": self.squares_y,
            "marker_mm": round(self.marker_m * 1e3, 9),
            "dictionary": self.dictionary,
            "legacy": self.legacy,
        }

    def size_hint(self) -> str:
        """How the board's size is counted, for a message that it was not found."""
        if self.target == "chessboard":
            nx, ny = self.inner_corners
            return (
                f" (--inner-corners counts the corners where four squares meet: a board of "
                f"{nx}x{ny} squares has {nx - 1}x{ny - 1})"
            )
        return " (--squares-x/-y count the squares, markers included)"

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description (stored in the calibration's info): a chessboard without the
        ChArUco-only marker size, dictionary and legacy flag."""
        board = asdict(self)
        if self.target == "chessboard":
            for key in ("marker_m", "dictionary", "legacy"):
                board.pop(key)
        return board

    @property
    def n_corners(self) -> int:
        """Number of inner chessboard corners."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    def board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV ChArUco board object (ChArUco targets only)."""
        if self.target != "charuco":
            raise CalibrationError(
                f"this needs a ChArUco board, not a {self.describe()}; use --target charuco"
            )
        dict_id = getattr(cv2.aruco, self.dictionary, None)
        if not self.dictionary.startswith("DICT_") or dict_id is None:
            known = [n for n in dir(cv2.aruco) if n.startswith("DICT_")]
            raise CalibrationError(
                f"unknown ArUco dictionary {self.dictionary!r}; known: {', '.join(known)}"
            )
        dictionary = cv2.aruco.getPredefinedDictionary(dict_id)
        n_markers = (self.squares_x * self.squares_y) // 2
        if n_markers > dictionary.bytesList.shape[0]:
            raise CalibrationError(
                f"a {self.squares_x}x{self.squares_y} board needs {n_markers} "
                f"markers but {self.dictionary} has only "
                f"{dictionary.bytesList.shape[0]}"
            )
        board = cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary
        )
        board.setLegacyPattern(self.legacy)
        return board

    def object_points(self) -> np.ndarray:
        """Board-frame coordinates (n_corners×3, metres) indexed by corner id (row-major inner
        corners, x fastest; ChArUco's corner ids for ChArUco boards)."""
        if self.target == "charuco":
            return np.asarray(self.board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)
        nx, ny = self.inner_corners
        col, row = np.meshgrid(np.arange(1, nx + 1), np.arange(1, ny + 1))
        return np.column_stack([col.ravel(), row.ravel(), np.zeros(nx * ny)]) * self.square_m


SUBPIX = "cornerSubPix"


@dataclass(frozen=True)
class Candidate:
    """One refinement of a view's corners: the method (``cornerSubPix``, the crossing of a
    chessboard's edge lines or the ChArUco detector's own), its half-window (0: none) and the
    corners (n×2, numbered as the detection's ids)."""

    method: str
    half_window: int
    corners: np.ndarray

    @property
    def label(self) -> str:
        """The method and its window in words, e.g. ``cornerSubPix half 8``."""
        return f"{self.method} half {self.half_window}" if self.half_window else self.method


@dataclass(frozen=True)
class Detection:
    """Corners found in one image: ids (n,) and pixel positions (n×2). A detection made for
    calibration also holds its refinement candidates (the first is ``corners``), which
    detector found the board and the board's edge width (10-90 %, px)."""

    ids: np.ndarray
    corners: np.ndarray
    candidates: tuple[Candidate, ...] = ()
    finder: str = ""
    edge_width_px: float = float("nan")

    def __len__(self) -> int:
        return len(self.ids)

    def corners_of(self, candidate: Candidate | None) -> np.ndarray:
        """The corners of ``candidate``; this detection's own when None."""
        return self.corners if candidate is None else candidate.corners

    def using(self, candidate: Candidate) -> Detection:
        """This detection with the corners of ``candidate`` (its candidates dropped)."""
        return Detection(self.ids, candidate.corners, (), self.finder, self.edge_width_px)


def _empty() -> Detection:
    return Detection(np.zeros(0, np.int32), np.zeros((0, 2), np.float64))


class BoardDetector:
    """Finds the target's corners in images: ChArUco corners with ``CharucoDetector``,
    chessboard corners with ``findChessboardCorners`` (``findChessboardCornersSB`` where it
    fails), sub-pixel refined in the adaptive window. With ``candidates`` each detection also
    carries the other refinements worth comparing (see :class:`Detection`): cornerSubPix in
    OpenCV's larger windows and, for chessboards, the crossings of the board's edge lines
    (:mod:`vbfe.calib.edge_lines`)."""

    def __init__(self, spec: BoardSpec, candidates: bool = False) -> None:
        self.spec = spec
        self.with_candidates = candidates
        self._detector = (
            cv2.aruco.CharucoDetector(spec.board()) if spec.target == "charuco" else None
        )

    def detect(self, image: np.ndarray) -> Detection:
        """Corners in one BGR or grey image; empty when the board is not seen."""
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self._detector is None:
            return self._detect_chessboard(grey)
        corners, ids, _, _ = self._detector.detectBoard(grey)
        if ids is None or len(ids) == 0:
            return _empty()
        ids = ids.reshape(-1).astype(np.int32)
        order = np.argsort(ids)
        ids, corners = ids[order], corners.reshape(-1, 2).astype(np.float64)[order]
        if not self.with_candidates:
            return Detection(ids, corners)
        own = Candidate("CharucoDetector", 0, corners)
        row = self.spec.squares_x - 1
        spacing = _charuco_spacing(ids, corners, row)
        windows = subpix_windows(spacing) if np.isfinite(spacing) else []
        refined = [Candidate(SUBPIX, h, refine(grey, corners, h)) for h in windows]
        return Detection(
            ids, corners, (own, *refined), "CharucoDetector", edge_width_px(grey, ids, corners, row)
        )

    def _detect_chessboard(self, grey: np.ndarray) -> Detection:
        inner = self.spec.inner_corners
        first = find_chessboard(grey, inner)
        if first is None:
            return _empty()
        start = canonical(first[0].reshape(-1, 2).astype(np.float64), inner)
        spacing = corner_spacing(start, inner)
        windows = subpix_windows(spacing)
        ids = np.arange(len(start), dtype=np.int32)
        corners = refine(grey, start, windows[0])
        if not self.with_candidates:
            return Detection(ids, corners)
        found = [Candidate(SUBPIX, h, refine(grey, start, h)) for h in windows[1:]]
        crossing = edge_line_corners(grey, corners, inner)
        if crossing is not None:
            found.append(Candidate(EDGE_LINES, 0, crossing))
        return Detection(
            ids,
            corners,
            (Candidate(SUBPIX, windows[0], corners), *found),
            first[1],
            edge_width_px(grey, ids, corners, inner[0]),
        )


def _charuco_spacing(ids: np.ndarray, corners: np.ndarray, row_length: int) -> float:
    """Smallest distance (px) between ChArUco corners next to each other on the board; NaN
    when no two are neighbours."""
    a, b = neighbour_pairs(ids, row_length)
    if len(a) == 0:
        return float("nan")
    return float(np.linalg.norm(corners[a] - corners[b], axis=1).min())


def board_image(spec: BoardSpec, px_per_mm: float = 20.0, margin_mm: float = 2.0) -> np.ndarray:
    """A grey image of the ChArUco board with a white margin, ``px_per_mm`` pixels per mm."""
    width_mm = spec.squares_x * spec.square_m * 1e3 + 2 * margin_mm
    height_mm = spec.squares_y * spec.square_m * 1e3 + 2 * margin_mm
    size = (int(round(width_mm * px_per_mm)), int(round(height_mm * px_per_mm)))
    return spec.board().generateImage(
        size, marginSize=int(round(margin_mm * px_per_mm)), borderBits=1
    )


def write_board(
    spec: BoardSpec, out_stem: str | Path, px_per_mm: float = 40.0, margin_mm: float = 2.0
) -> tuple[Path, Path]:
    """Write ``<stem>.png`` and a true-scale ``<stem>.pdf`` of the board; returns both paths."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    out_stem = Path(out_stem)
    out_stem.parent.mkdir(parents=True, exist_ok=True)
    image = board_image(spec, px_per_mm, margin_mm)
    png = out_stem.with_suffix(".png")
    dpi = px_per_mm * 25.4
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise CalibrationError(f"OpenCV could not encode {png}")
    write_bytes_atomic(png, encoded.tobytes())
    # PDF page exactly the board's physical size (inches = mm / 25.4)
    height_px, width_px = image.shape
    fig = plt.figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.imshow(image, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    ax.set_axis_off()
    pdf = out_stem.with_suffix(".pdf")
    try:
        save_figure(fig, pdf, dpi=dpi)
    finally:
        plt.close(fig)
    return png, pdf
