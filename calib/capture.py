"""Interactive-style view collection: keep views at new board poses until coverage is enough.

Each offered left/right pair is checked like ROS ``camera_calibration`` does: the board must be
found in both eyes, sharp (variance of the Laplacian over the board), and at a pose unlike the
views kept so far; coverage is tracked as X, Y, size and skew bars of the left view.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from vbfe.calib.board import BoardDetector, BoardSpec, Detection
from vbfe.calib.options import CalibOptions, calib_field
from vbfe.calib.views import load_views, save_views

# The spread each coverage parameter must reach for a full bar (ROS camera_calibration's, with
# size relaxed from 0.4 to 0.25: an endoscope's working range rarely lets the board fill the image).
PARAM_RANGES = {"x": 0.7, "y": 0.7, "size": 0.25, "skew": 0.5}
# sharpness() per target on the ChArUco scale: a plain chessboard has no marker edges, so the
# same focus gives about 3.5x less Laplacian energy per square (sharp renders 4-6, blurred 1-2)
SHARPNESS_SCALE = {"charuco": 1.0, "chessboard": 3.5}


@dataclass
class CaptureOptions(CalibOptions):
    """Thresholds for keeping a view (defaults match the ``[calib]`` table)."""

    min_corners: int = calib_field("min_corners")
    min_views: int = calib_field("capture_views")
    max_views: int = calib_field("capture_max_views")
    min_sharpness: float = calib_field("min_sharpness")  # see sharpness()
    min_pose_distance: float = calib_field("min_pose_distance")  # sum of |Δ| of X, Y, size, skew


@dataclass
class Verdict:
    """What happened to one offered view."""

    kept: bool
    reason: str
    params: np.ndarray | None = None  # x, y, size, skew in [0, 1]
    left: Detection | None = None
    right: Detection | None = None


def pose_params(det: Detection, spec: BoardSpec, image_size: tuple[int, int]) -> np.ndarray:
    """ROS-style view parameters in [0, 1]: X, Y of the board centre, size (sqrt of the area
    fraction) and skew (how far the board's axes are from perpendicular in the image)."""
    w, h = image_size
    corners = det.corners.astype(np.float32)
    hull = cv2.convexHull(corners)
    size = np.sqrt(cv2.contourArea(hull) / (w * h))
    board_xy = spec.object_points()[det.ids, :2]
    H, _ = cv2.findHomography(board_xy, corners)
    centre = board_xy.mean(axis=0)
    pts = np.array([centre, centre + [1e-3, 0], centre + [0, 1e-3]], np.float64)
    img = cv2.perspectiveTransform(pts.reshape(-1, 1, 2), H).reshape(-1, 2)
    ax, ay = img[1] - img[0], img[2] - img[0]
    angle = np.arccos(np.clip(ax @ ay / (np.linalg.norm(ax) * np.linalg.norm(ay)), -1, 1))
    skew = min(1.0, 2 * abs(np.pi / 2 - angle))
    mean = corners.mean(axis=0)
    extent = corners.max(axis=0) - corners.min(axis=0)  # as ROS: 0/1 = board touching the edge
    x = (mean[0] - extent[0] / 2) / max(w - extent[0], 1.0)
    y = (mean[1] - extent[1] / 2) / max(h - extent[1], 1.0)
    return np.clip(np.array([x, y, size, skew]), 0.0, 1.0)


def sharpness(image: np.ndarray, det: Detection) -> float:
    """Variance of the Laplacian over the board's bounding box, normalised by the grey-level
    variance there and scaled by the square size in pixels, so it does not depend on contrast
    or on how large the board appears (sharp renders ≳ 15, a 5-px motion blur ≲ 9)."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    x0, y0 = np.floor(det.corners.min(axis=0)).astype(int)
    x1, y1 = np.ceil(det.corners.max(axis=0)).astype(int) + 1
    roi = grey[max(y0, 0) : y1, max(x0, 0) : x1].astype(np.float64)
    square_px = np.sqrt(cv2.contourArea(cv2.convexHull(det.corners.astype(np.float32))) / len(det))
    return float(cv2.Laplacian(roi, cv2.CV_64F).var() / max(roi.var(), 1e-9) * square_px)


@dataclass
class ViewCollector:
    """Decides which offered views to keep and tracks coverage."""

    spec: BoardSpec
    options: CaptureOptions = field(default_factory=CaptureOptions)
    pairs: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    params: list[np.ndarray] = field(default_factory=list)
    corners: list[np.ndarray] = field(default_factory=list)  # of each kept view's left eye

    def __post_init__(self) -> None:
        self._detector = BoardDetector(self.spec)

    def offer(self, left: np.ndarray, right: np.ndarray) -> Verdict:
        """Check one pair and keep it when it is good and new."""
        dl, dr = self._detector.detect(left), self._detector.detect(right)
        common = len(np.intersect1d(dl.ids, dr.ids))
        if common < self.options.min_corners:
            return Verdict(
                False,
                f"board not seen in both eyes ({len(dl)} left, {len(dr)} right "
                f"corners, {common} common; need {self.options.min_corners})",
                left=dl,
                right=dr,
            )
        sharp = min(sharpness(left, dl), sharpness(right, dr)) * SHARPNESS_SCALE[self.spec.target]
        params = pose_params(dl, self.spec, (left.shape[1], left.shape[0]))
        if sharp < self.options.min_sharpness:
            return Verdict(
                False,
                f"blurred (sharpness {sharp:.0f} < "
                f"{self.options.min_sharpness:.0f}); hold the board still",
                params,
                dl,
                dr,
            )
        if self.params:
            nearest = min(float(np.abs(params - p).sum()) for p in self.params)
            if nearest < self.options.min_pose_distance:
                return Verdict(
                    False,
                    f"pose too close to a kept view (distance {nearest:.2f} < "
                    f"{self.options.min_pose_distance:.2f}); move or tilt the board",
                    params,
                    dl,
                    dr,
                )
        self.pairs.append((left, right))
        self.params.append(params)
        self.corners.append(dl.corners)
        return Verdict(True, f"kept view {len(self.pairs)}", params, dl, dr)

    def keep(self, left: np.ndarray, right: np.ndarray) -> None:
        """Count an earlier kept view (e.g. from a resumed capture) without checks."""
        det = self._detector.detect(left)
        if len(det) >= 4:
            self.pairs.append((left, right))
            self.params.append(pose_params(det, self.spec, (left.shape[1], left.shape[0])))
            self.corners.append(det.corners)

    def coverage(self) -> dict[str, float]:
        """Progress (0..1) of the X, Y, size and skew bars."""
        if not self.params:
            return dict.fromkeys(PARAM_RANGES, 0.0)
        p = np.array(self.params)
        spread = p.max(axis=0) - p.min(axis=0)
        return {
            k: float(min(1.0, s / r))
            for (k, r), s in zip(PARAM_RANGES.items(), spread, strict=False)
        }

    def coverage_map(
        self, image_size: tuple[int, int], cells: tuple[int, int] = (8, 6)
    ) -> np.ndarray:
        """Where the kept views' left corners lie: counts per cell of a ``cells`` (columns,
        rows) grid over an image of ``image_size`` (width, height), shape (rows, columns)."""
        grid = np.zeros((cells[1], cells[0]), np.int64)
        if self.corners:
            xy = np.concatenate(self.corners).reshape(-1, 2)
            col = np.clip((xy[:, 0] * cells[0] / image_size[0]).astype(int), 0, cells[0] - 1)
            row = np.clip((xy[:, 1] * cells[1] / image_size[1]).astype(int), 0, cells[1] - 1)
            np.add.at(grid, (row, col), 1)
        return grid

    @property
    def enough(self) -> bool:
        """Enough views kept and every bar full (or the view limit reached)."""
        full = all(v >= 1.0 for v in self.coverage().values())
        return (len(self.pairs) >= self.options.min_views and full) or len(
            self.pairs
        ) >= self.options.max_views


def rejection_kind(reason: str) -> str:
    """What a rejected view's reason counts as (its words before the numbers or remedy)."""
    return reason.split(" (")[0].split(";")[0]


def coverage_text(coverage: dict[str, float], n_views: int, width: int = 20) -> str:
    """Text bars, e.g. ``X [##########----------] 50%``, one line."""
    bars = [
        f"{k.upper() if len(k) == 1 else k} [{'#' * round(v * width)}"
        f"{'-' * (width - round(v * width))}] {v * 100:3.0f}%"
        for k, v in coverage.items()
    ]
    return f"views {n_views:3d}  " + "  ".join(bars)


def annotate(image: np.ndarray, det: Detection, coverage: dict[str, float]) -> np.ndarray:
    """The image with detected corners and coverage bars drawn on it (for a live preview)."""
    out = image.copy()
    if len(det):
        cv2.aruco.drawDetectedCornersCharuco(
            out,
            det.corners.reshape(-1, 1, 2).astype(np.float32),
            det.ids.reshape(-1, 1),
            (0, 255, 0),
        )
    for i, (k, v) in enumerate(coverage.items()):
        y = 12 + 14 * i
        cv2.putText(out, k, (4, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1)
        cv2.rectangle(out, (40, y - 4), (140, y + 4), (80, 80, 80), -1)
        cv2.rectangle(out, (40, y - 4), (40 + int(100 * v), y + 4), (0, 200, 0), -1)
    return out


@dataclass
class CaptureResult:
    """Views kept in this run (saved to ``folder``), frames looked at, final coverage."""

    folder: Path
    names: list[str]  # of the views saved in this run
    frames_seen: int
    coverage: dict[str, float]
    enough: bool
    rejections: dict[str, int]  # first word of the reason -> count


def capture_views(
    frames: Iterable[tuple[np.ndarray, np.ndarray]],
    spec: BoardSpec,
    folder: str | Path,
    options: CaptureOptions | None = None,
    on_view: Callable[[Verdict, ViewCollector, np.ndarray], None] | None = None,
) -> CaptureResult:
    """Offer ``frames`` to a :class:`ViewCollector` until it has enough views; save the kept
    views as PNG pairs ``view_NNN_left.png`` / ``view_NNN_right.png`` in ``folder``.
    ``on_view(verdict, collector, left_image)`` is called after each offered view.

    Views already in ``folder`` count towards coverage, so capture can be resumed.
    """
    folder = Path(folder)
    collector = ViewCollector(spec, options or CaptureOptions())
    if folder.is_dir() and any(folder.glob("*_left.png")):
        for left, right in load_views(folder).pairs:
            collector.keep(left, right)
    first_new = len(collector.pairs)
    seen = 0
    rejections: dict[str, int] = {}
    for left, right in frames:
        if collector.enough:
            break
        seen += 1
        verdict = collector.offer(left, right)
        if verdict.kept:
            save_views(folder, [(left, right)], [f"view_{len(collector.pairs) - 1:03d}"])
        else:
            key = rejection_kind(verdict.reason)
            rejections[key] = rejections.get(key, 0) + 1
        if on_view:
            on_view(verdict, collector, left)
    names = [f"view_{i:03d}" for i in range(first_new, len(collector.pairs))]
    return CaptureResult(folder, names, seen, collector.coverage(), collector.enough, rejections)


def camera_frames(
    camera, max_frames: int, timeout_s: float = 2.0
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Left/right images from an open :class:`~vbfe.drivers.camera.base.StereoCamera`."""
    for _ in range(max_frames):
        frame = camera.read(timeout_s)
        if frame is not None:
            yield frame.left, frame.right
