"""Calibration views from the simulated bench: a board waved in front of the endoscope.

Until the bench's live camera shows a board, ``capture`` on the simulated rig uses these
frames: random board poses rendered with :mod:`vbfe.drivers.sim.charuco_scene`, where the
operator sometimes holds the board still (repeated poses) and sometimes moves it during the
exposure (motion blur), so the capture checks have something to refuse.
"""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np

from vbfe.calib.board import BoardSpec
from vbfe.drivers.sim.charuco_scene import (ChessboardPattern, random_board_poses,
                                            render_board_views)
from vbfe.drivers.sim.rig import StereoRig

DISTANCE_M = (0.03, 0.07)  # keeps the 3 mm board's markers readable at 640×360


def scene_board(spec: BoardSpec) -> cv2.aruco.CharucoBoard | ChessboardPattern:
    """The board object the bench renders for ``spec`` (ChArUco or plain chessboard)."""
    if spec.target == "chessboard":
        return ChessboardPattern(spec.inner_corners, spec.square_m)
    return spec.board()


def motion_blur(image: np.ndarray, length_px: int, angle_deg: float) -> np.ndarray:
    """The image smeared along a line of ``length_px`` at ``angle_deg``."""
    kernel = np.zeros((length_px, length_px), np.float32)
    c = (length_px - 1) / 2
    dx, dy = np.cos(np.radians(angle_deg)) * c, np.sin(np.radians(angle_deg)) * c
    cv2.line(kernel, (round(c - dx), round(c - dy)), (round(c + dx), round(c + dy)), 1.0, 1)
    return cv2.filter2D(image, -1, kernel / kernel.sum())


def simulated_board_frames(rig: StereoRig, spec: BoardSpec, n_frames: int,
                           rng: np.random.Generator, p_still: float = 0.25,
                           p_blur: float = 0.15, blur_px: int = 5
                           ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """``n_frames`` left/right pairs of the board at random poses (some repeated, some blurred)."""
    board = scene_board(spec)
    poses = random_board_poses(n_frames, rng, distance_m=DISTANCE_M, rig=rig, board=board)
    previous = None
    for pose in poses:
        if previous is not None and rng.random() < p_still:
            pose = (previous[0] + rng.normal(0, 1e-3, 3), previous[1] + rng.normal(0, 2e-5, 3))
        (left, right), = render_board_views(rig, board, [pose], rng=rng)
        if rng.random() < p_blur:
            angle = rng.uniform(0, 180)
            left, right = motion_blur(left, blur_px, angle), motion_blur(right, blur_px, angle)
        previous = pose
        yield left, right


def _projector_sees(rig: StereoRig, board_points: np.ndarray, pose, margin_px: float = 8) -> bool:
    R_board, _ = cv2.Rodrigues(np.asarray(pose[0], np.float64).reshape(3))
    points = board_points @ R_board.T + np.asarray(pose[1], np.float64)
    uv = rig.projector.project(points, rig.R_proj, rig.T_proj)
    p = rig.projector
    return bool(np.all((uv > margin_px) & (uv < np.array([p.width, p.height]) - margin_px)))


def simulated_gray_code_captures(rig: StereoRig, spec: BoardSpec, n_poses: int,
                                 rng: np.random.Generator, max_tilt_deg: float = 45.0) -> list:
    """Left-camera Gray-code captures of the board at ``n_poses`` random poses inside the
    projector's field, rendered with the bench's ray caster."""
    from vbfe.calib.projector import GrayCodeCapture, projector_images
    from vbfe.drivers.sim.charuco_scene import board_texture
    from vbfe.drivers.sim.render import StereoRenderer
    from vbfe.drivers.sim.tissue import ImageTexture, Plane

    board = spec.board()
    board_points = spec.object_points()
    px_per_m = 40000.0
    texture = ImageTexture(board_texture(board, px_per_m) / 255.0, px_per_m,
                           (0.5 / px_per_m, 0.5 / px_per_m))
    candidates = random_board_poses(8 * n_poses, rng, distance_m=DISTANCE_M,
                                    max_tilt_deg=max_tilt_deg, rig=rig, board=board)
    poses = [p for p in candidates if _projector_sees(rig, board_points, p)][:n_poses]
    renderer = StereoRenderer(rig, rng=rng)
    white, black, patterns = projector_images((rig.projector.width, rig.projector.height))
    captures = []
    for rvec, tvec in poses:
        R_board, _ = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3))
        plane = Plane(R_board, np.asarray(tvec, np.float64), texture=texture)
        shots = []
        for image in [white, black, *patterns]:
            renderer.set_pattern(image, distance_m=float(np.linalg.norm(tvec)))
            shots.append(cv2.cvtColor(renderer.render_eye(0, plane), cv2.COLOR_BGR2GRAY))
        captures.append(GrayCodeCapture(shots[0], shots[1], shots[2:]))
    return captures


def bench_rig(bench_table: dict) -> StereoRig:
    """The true rig of the simulated bench the ``[bench]`` table describes."""
    from vbfe.drivers.sim import SimBench

    return SimBench.from_config(bench_table).rig
