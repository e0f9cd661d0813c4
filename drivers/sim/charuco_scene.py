"""A calibration board (ChArUco or plain chessboard) in front of the simulated stereo endoscope.

A plain chessboard is a :class:`ChessboardPattern`, which offers the part of the
``cv2.aruco.CharucoBoard`` interface used here, so every function takes either.

Images are made by inverse mapping: each output pixel (with the rig's lens distortion) is
undistorted into a ray, the ray is intersected with the board plane, and the board texture is
sampled there with ``cv2.remap``. Rendering is supersampled and block-averaged, so edges and
corners are anti-aliased and land where the true projection puts them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.drivers.sim.optics import Optics
from vbfe.drivers.sim.rays import camera_rays, intersect_plane
from vbfe.drivers.sim.rig import PinholeCamera, StereoRig

Pose = tuple[np.ndarray, np.ndarray]  # (rvec, tvec): board frame → left-camera frame, metres

BACKGROUND = 110  # grey level around the board
WHITE = 225
BLACK = 25


class ChessboardPattern:
    """A printed chessboard with ``inner_corners`` (nx, ny) and a one-square white margin.

    Board frame as ChArUco's: origin at the outer corner of the printed sheet (margin included),
    x along the rows, z into the board; :meth:`getChessboardCorners` gives the inner corners
    row by row, x fastest (OpenCV's ``findChessboardCorners`` order).
    """

    def __init__(self, inner_corners: tuple[int, int], square_m: float) -> None:
        self.inner_corners = (int(inner_corners[0]), int(inner_corners[1]))
        self.square_m = float(square_m)

    def getSquareLength(self) -> float:  # noqa: N802 (CharucoBoard's name)
        """Side of one square (m)."""
        return self.square_m

    def getChessboardSize(self) -> tuple[int, int]:  # noqa: N802
        """The sheet in squares: the board's squares plus the margin on each side."""
        return self.inner_corners[0] + 3, self.inner_corners[1] + 3

    def getChessboardCorners(self) -> np.ndarray:  # noqa: N802
        """Inner corners (n×3, m) in the board frame."""
        nx, ny = self.inner_corners
        col, row = np.meshgrid(np.arange(2, nx + 2), np.arange(2, ny + 2))
        return (
            np.column_stack([col.ravel(), row.ravel(), np.zeros(nx * ny)]) * self.square_m
        ).astype(np.float32)

    def generateImage(
        self,
        size: tuple[int, int],
        marginSize: int = 0,  # noqa: N802, N803
        borderBits: int = 1,
    ) -> np.ndarray:  # noqa: N803 (unused, as ChArUco)
        """The sheet as a grey ``uint8`` image of ``size`` (w, h) pixels, black top-left
        square, white margin, plus ``marginSize`` extra white pixels around."""
        w, h = size[0] - 2 * marginSize, size[1] - 2 * marginSize
        sx, sy = self.getChessboardSize()
        u = (np.arange(w) + 0.5) * sx / w
        v = (np.arange(h) + 0.5) * sy / h
        cu, cv_ = np.floor(u).astype(int), np.floor(v).astype(int)
        black = (cu[None, :] + cv_[:, None]) % 2 == 0
        inside = ((cu >= 1) & (cu <= sx - 2))[None, :] & ((cv_ >= 1) & (cv_ <= sy - 2))[:, None]
        sheet = np.where(black & inside, 0, 255).astype(np.uint8)
        return cv2.copyMakeBorder(
            sheet, marginSize, marginSize, marginSize, marginSize, cv2.BORDER_CONSTANT, value=255
        )


def board_size_m(board: cv2.aruco.CharucoBoard | ChessboardPattern) -> tuple[float, float]:
    """Board width and height in metres; raises if the board was not built in metres."""
    square = float(board.getSquareLength())
    if not 0 < square < 0.1:
        raise DeviceError(
            f"ChArUco board square length {square} does not look like metres; "
            "build the board with lengths in metres (e.g. 0.003 for 3 mm)"
        )
    nx, ny = board.getChessboardSize()
    return nx * square, ny * square


def board_texture(board: cv2.aruco.CharucoBoard | ChessboardPattern, px_per_m: float) -> np.ndarray:
    """The board image (grey uint8) with ``px_per_m`` texture pixels per metre, no margin."""
    w_m, h_m = board_size_m(board)
    size = (int(round(w_m * px_per_m)), int(round(h_m * px_per_m)))
    image = board.generateImage(size, marginSize=0, borderBits=1)
    return (BLACK + (WHITE - BLACK) * (image.astype(np.float32) / 255.0)).astype(np.float32)


@dataclass(frozen=True)
class BoardTarget:
    """Any planar calibration target as the bench renders it: a grey texture whose pixel
    ``(0, 0)`` corner is the board origin, and the board-frame points a detector finds."""

    texture: np.ndarray  # float32 grey levels
    px_per_m: float
    object_points: np.ndarray  # n×3, metres, z = 0

    @property
    def size_m(self) -> tuple[float, float]:
        """Width and height of the textured area in metres."""
        return self.texture.shape[1] / self.px_per_m, self.texture.shape[0] / self.px_per_m


def charuco_target(
    board: cv2.aruco.CharucoBoard | ChessboardPattern, px_per_m: float = 40000.0
) -> BoardTarget:
    """The ChArUco ``board`` (built in metres) as a :class:`BoardTarget`."""
    return BoardTarget(
        board_texture(board, px_per_m),
        px_per_m,
        np.asarray(board.getChessboardCorners(), np.float64).reshape(-1, 3),
    )


def _geometry(
    board: cv2.aruco.CharucoBoard | BoardTarget,
) -> tuple[tuple[float, float], np.ndarray]:
    """Size (m) and object points of a ChArUco board or a target."""
    if isinstance(board, BoardTarget):
        return board.size_m, board.object_points
    return board_size_m(board), np.asarray(board.getChessboardCorners(), np.float64)


def _render_view(
    camera: PinholeCamera,
    R: np.ndarray | None,
    T: np.ndarray | None,
    texture: np.ndarray,
    px_per_m: float,
    pose: Pose,
    supersample: int,
) -> np.ndarray:
    origin, dirs = camera_rays(camera, R, T, supersample)
    R_board, _ = cv2.Rodrigues(np.asarray(pose[0], np.float64).reshape(3))
    x, y, _, valid = intersect_plane(origin, dirs, R_board, np.asarray(pose[1], np.float64))
    map_x = x * np.float32(px_per_m) - np.float32(0.5)
    map_y = y * np.float32(px_per_m) - np.float32(0.5)
    map_x[~valid] = -1e6
    image = cv2.remap(
        texture,
        map_x,
        map_y,
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=BACKGROUND,
    )
    if supersample > 1:
        image = cv2.resize(image, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    return image


def render_board_views(
    rig: StereoRig,
    board: cv2.aruco.CharucoBoard | BoardTarget,
    poses: list[Pose],
    board_px_per_m: float = 40000.0,
    optics: Optics | None = None,
    supersample: int = 3,
    rng: np.random.Generator | None = None,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Left/right BGR ``uint8`` views of ``board`` at each pose (board → left camera), in
    even room light.

    A ChArUco board must be built with lengths in metres (it is textured at
    ``board_px_per_m``); a :class:`BoardTarget` brings its own texture. ``optics`` blur,
    darken, add noise to and compress the images (default: a mild blur and a little sensor
    noise); distortion is the rig's, applied exactly.
    """
    rng = np.random.default_rng() if rng is None else rng
    if not isinstance(board, BoardTarget):
        board = charuco_target(board, board_px_per_m)
    texture, board_px_per_m = board.texture, board.px_per_m
    views = []
    for pose in poses:
        pair = [
            _render_eye(
                camera,
                R,
                T,
                texture,
                board_px_per_m,
                pose,
                supersample,
                optics or Optics(),
                rng,
            )
            for camera, R, T in ((rig.left, None, None), (rig.right, rig.R, rig.T))
        ]
        views.append((pair[0], pair[1]))
    return views


def render_mono_views(
    camera: PinholeCamera,
    board: cv2.aruco.CharucoBoard,
    poses: list[Pose],
    board_px_per_m: float = 40000.0,
    optics: Optics | None = None,
    supersample: int = 3,
    rng: np.random.Generator | None = None,
) -> list[np.ndarray]:
    """BGR ``uint8`` views of ``board`` (board → camera poses) seen by one camera, rendered as
    :func:`render_board_views` renders each eye."""
    rng = np.random.default_rng() if rng is None else rng
    texture = board_texture(board, board_px_per_m)
    return [
        _render_eye(
            camera,
            None,
            None,
            texture,
            board_px_per_m,
            pose,
            supersample,
            optics or Optics(),
            rng,
        )
        for pose in poses
    ]


def _render_eye(
    camera: PinholeCamera,
    R: np.ndarray | None,
    T: np.ndarray | None,
    texture: np.ndarray,
    px_per_m: float,
    pose: Pose,
    supersample: int,
    optics: Optics,
    rng: np.random.Generator,
) -> np.ndarray:
    grey = _render_view(camera, R, T, texture, px_per_m, pose, supersample)
    return cv2.cvtColor(optics.image(grey, rng), cv2.COLOR_GRAY2BGR)


def _rotation(tilt_x_deg: float, tilt_y_deg: float, roll_deg: float) -> np.ndarray:
    rx, _ = cv2.Rodrigues(np.array([math.radians(tilt_x_deg), 0.0, 0.0]))
    ry, _ = cv2.Rodrigues(np.array([0.0, math.radians(tilt_y_deg), 0.0]))
    rz, _ = cv2.Rodrigues(np.array([0.0, 0.0, math.radians(roll_deg)]))
    return rx @ ry @ rz


def visible_fraction(
    rig: StereoRig, board: cv2.aruco.CharucoBoard | BoardTarget, pose: Pose, margin_px: float = 4.0
) -> float:
    """Fraction of chessboard corners inside both views (with a margin), board facing the camera."""
    _, corners = _geometry(board)
    R_board, _ = cv2.Rodrigues(np.asarray(pose[0], np.float64).reshape(3))
    points = corners @ R_board.T + np.asarray(pose[1], np.float64).reshape(3)
    if np.any(points[:, 2] <= 0):
        return 0.0
    inside = np.ones(len(points), dtype=bool)
    for camera, R, T in ((rig.left, None, None), (rig.right, rig.R, rig.T)):
        uv = camera.project(points, R, T)
        inside &= (
            (uv[:, 0] >= margin_px)
            & (uv[:, 0] <= camera.width - 1 - margin_px)
            & (uv[:, 1] >= margin_px)
            & (uv[:, 1] <= camera.height - 1 - margin_px)
        )
    return float(inside.mean())


def random_board_poses(
    n: int,
    rng: np.random.Generator,
    distance_m: tuple[float, float] = (0.04, 0.09),
    max_tilt_deg: float = 35.0,
    max_roll_deg: float = 25.0,
    rig: StereoRig | None = None,
    board: cv2.aruco.CharucoBoard | BoardTarget | None = None,
    min_visible: float = 0.85,
    max_tries: int = 2000,
    accept: Callable[[Pose], bool] | None = None,
) -> list[Pose]:
    """``n`` varied board poses (rvec, tvec; board → left camera) facing the endoscope.

    The board centre is placed on a random line of sight at a random distance, tilted up to
    ``max_tilt_deg`` about x and y and rolled up to ``max_roll_deg``. With ``rig`` and ``board``
    given, poses are kept only when at least ``min_visible`` of the chessboard corners are in
    both views; without them the board centre is kept within ±20° of the optical axis.
    ``accept(pose)`` may refuse more poses (e.g. those outside the projector's field).
    """
    if (rig is None) != (board is None):
        raise ValueError("give both rig and board, or neither")
    half = np.zeros(3)
    if board is not None:
        (w_m, h_m), _ = _geometry(board)
        half = np.array([w_m / 2, h_m / 2, 0.0])
    poses: list[Pose] = []
    for _ in range(max_tries):
        if len(poses) == n:
            break
        R_board = _rotation(
            rng.uniform(-max_tilt_deg, max_tilt_deg),
            rng.uniform(-max_tilt_deg, max_tilt_deg),
            rng.uniform(-max_roll_deg, max_roll_deg),
        )
        distance = rng.uniform(*distance_m)
        if rig is not None:
            hx = math.atan((rig.left.width / 2) / rig.left.K[0, 0])
            hy = math.atan((rig.left.height / 2) / rig.left.K[1, 1])
        else:
            hx = hy = math.radians(20.0)
        direction = np.array(
            [math.tan(rng.uniform(-0.6, 0.6) * hx), math.tan(rng.uniform(-0.6, 0.6) * hy), 1.0]
        )
        centre = direction / np.linalg.norm(direction) * distance
        tvec = centre - R_board @ half
        rvec, _ = cv2.Rodrigues(R_board)
        pose = (rvec.reshape(3), tvec)
        if (rig is None or board is None or visible_fraction(rig, board, pose) >= min_visible) and (
            accept is None or accept(pose)
        ):
            poses.append(pose)
    if len(poses) < n:
        raise DeviceError(
            f"could only place {len(poses)} of {n} board poses in view; widen "
            "distance_m or lower max_tilt_deg / min_visible"
        )
    return poses
