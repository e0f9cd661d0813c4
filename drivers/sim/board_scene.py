"""A calibration board in front of the bench's endoscope: the ``board`` scene of :class:`SimBench`.

The board moves like an operator moves it. With ``hold_s = 0`` it is hand-held: a new random
pose every frame, sometimes held still (the pose repeats with a small jitter) and sometimes
moved during the exposure (motion blur), so the capture checks have something to refuse. With
``hold_s > 0`` it rests at each pose for that long (on a stand, as for projector calibration)
and then jumps to the next. Poses are given, or drawn at random facing the endoscope (and
inside the projector's field when ``in_projector``).

In room light (nothing projected yet) the board is rendered by exact supersampled inverse
mapping (:func:`render_board_views`) through the camera's :class:`Optics`; once the projector
shows an image, the ray caster renders the board lit by it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.drivers.sim.charuco_scene import (
    BoardTarget,
    ChessboardPattern,
    Pose,
    charuco_target,
    random_board_poses,
    render_board_views,
)
from vbfe.drivers.sim.optics import Optics
from vbfe.drivers.sim.render import StereoRenderer
from vbfe.drivers.sim.rig import StereoRig
from vbfe.drivers.sim.tissue import ImageTexture, Plane

BOARDS = ("charuco", "chessboard")
DISTANCE_M = (0.03, 0.07)  # default range of random poses: keeps a 3 mm board readable at 640×360


def motion_blur(image: np.ndarray, length_px: int, angle_deg: float) -> np.ndarray:
    """The image smeared along a line of ``length_px`` at ``angle_deg``."""
    kernel = np.zeros((length_px, length_px), np.float32)
    c = (length_px - 1) / 2
    dx, dy = np.cos(np.radians(angle_deg)) * c, np.sin(np.radians(angle_deg)) * c
    cv2.line(kernel, (round(c - dx), round(c - dy)), (round(c + dx), round(c + dy)), 1.0, 1)
    return cv2.filter2D(image, -1, kernel / kernel.sum())


def board_target(
    kind: str,
    squares_x: int,
    squares_y: int,
    square_mm: float,
    marker_mm: float,
    dictionary: str,
    legacy: bool,
) -> BoardTarget:
    """The target a ``[bench]`` table's ``board_*`` keys describe (a chessboard of
    ``squares_x`` × ``squares_y`` squares has one inner corner fewer each way)."""
    if kind not in BOARDS:
        raise DeviceError(f"[bench] board must be one of {BOARDS}, got {kind!r}")
    if kind == "chessboard":
        if min(squares_x, squares_y) < 3 or square_mm <= 0:
            raise DeviceError(
                "[bench] a chessboard needs at least 3x3 squares and a positive board_square_mm"
            )
        return charuco_target(ChessboardPattern((squares_x - 1, squares_y - 1), square_mm * 1e-3))
    dict_id = getattr(cv2.aruco, str(dictionary), None)
    if not str(dictionary).startswith("DICT_") or dict_id is None:
        raise DeviceError(
            f"[bench] board_dictionary {dictionary!r} is not an ArUco dictionary "
            "(e.g. DICT_5X5_100)"
        )
    if not 0 < marker_mm < square_mm:
        raise DeviceError(
            f"[bench] board_marker_mm ({marker_mm}) must be positive and smaller "
            f"than board_square_mm ({square_mm})"
        )
    board = cv2.aruco.CharucoBoard(
        (int(squares_x), int(squares_y)),
        square_mm * 1e-3,
        marker_mm * 1e-3,
        cv2.aruco.getPredefinedDictionary(dict_id),
    )
    board.setLegacyPattern(bool(legacy))
    return charuco_target(board)


@dataclass(frozen=True)
class BoardView:
    """Where the board is in one frame, and whether it moved during the exposure."""

    pose: Pose
    blur_angle_deg: float | None  # None: sharp


class BoardScene:
    """The board's motion over true time and its rendering (see the module docstring)."""

    def __init__(
        self,
        rig: StereoRig,
        target: BoardTarget,
        rng: np.random.Generator,
        frame_period_ns: int,
        poses: list[Pose] | None = None,
        hold_s: float = 0.0,
        p_still: float = 0.25,
        p_blur: float = 0.15,
        blur_px: int = 5,
        distance_m: tuple[float, float] = DISTANCE_M,
        max_tilt_deg: float = 35.0,
        in_projector: bool = False,
        optics: Optics | None = None,
    ) -> None:
        if hold_s < 0 or not (0 <= p_still <= 1 and 0 <= p_blur <= 1) or blur_px < 2:
            raise DeviceError(
                "[bench] board_hold_s must be >= 0, board_p_still and board_p_blur "
                "in [0, 1], board_blur_px >= 2"
            )
        self.rig, self.target, self.rng = rig, target, rng
        self.slot_ns = int(round(hold_s * 1e9)) if hold_s > 0 else frame_period_ns
        self.hand_held = hold_s == 0
        self.p_still, self.p_blur, self.blur_px = p_still, p_blur, int(blur_px)
        self.distance_m, self.max_tilt_deg = (distance_m[0], distance_m[1]), max_tilt_deg
        self.in_projector = in_projector
        self.optics = optics
        self._given = list(poses or [])
        self._views: list[BoardView] = []
        self._texture = ImageTexture(
            target.texture / 255.0, target.px_per_m, (0.5 / target.px_per_m, 0.5 / target.px_per_m)
        )

    def _lit_by_projector(self, pose: Pose, margin_px: float = 8.0) -> bool:
        R_board, _ = cv2.Rodrigues(np.asarray(pose[0], np.float64).reshape(3))
        points = self.target.object_points @ R_board.T + np.asarray(pose[1], np.float64)
        p = self.rig.projector
        uv = p.project(points, self.rig.R_proj, self.rig.T_proj)
        return bool(np.all((uv > margin_px) & (uv < np.array([p.width, p.height]) - margin_px)))

    def _next_view(self) -> BoardView:
        j = len(self._views)
        if self._given:
            return BoardView(self._given[j % len(self._given)], None)
        if self.hand_held and j and self.rng.random() < self.p_still:
            rvec, tvec = self._views[-1].pose
            pose = (rvec + self.rng.normal(0, 1e-3, 3), tvec + self.rng.normal(0, 2e-5, 3))
        else:
            accept = self._lit_by_projector if self.in_projector else None
            (pose,) = random_board_poses(
                1,
                self.rng,
                distance_m=self.distance_m,
                max_tilt_deg=self.max_tilt_deg,
                rig=self.rig,
                board=self.target,
                accept=accept,
            )
        blurred = self.hand_held and self.rng.random() < self.p_blur
        return BoardView(pose, float(self.rng.uniform(0, 180)) if blurred else None)

    def view_at(self, true_ns: int) -> BoardView:
        """The board's pose (and blur) at true time ``true_ns``."""
        slot = int(true_ns // self.slot_ns)
        while len(self._views) <= slot:
            self._views.append(self._next_view())
        return self._views[slot]

    def surface_at(self, true_ns: int) -> Plane:
        """The board plane, textured, at true time ``true_ns``."""
        rvec, tvec = self.view_at(true_ns).pose
        R_board, _ = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3))
        return Plane(R_board, np.asarray(tvec, np.float64), texture=self._texture)

    def render(
        self, true_ns: int, renderer: StereoRenderer | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Both views at ``true_ns``: in room light (``renderer`` None) or lit by the pattern
        ``renderer`` holds."""
        view = self.view_at(true_ns)
        if renderer is None:
            ((left, right),) = render_board_views(
                self.rig, self.target, [view.pose], optics=self.optics, rng=self.rng
            )
        else:
            left, right = renderer.render(self.surface_at(true_ns))
        if view.blur_angle_deg is not None:
            left = motion_blur(left, self.blur_px, view.blur_angle_deg)
            right = motion_blur(right, self.blur_px, view.blur_angle_deg)
        return left, right
