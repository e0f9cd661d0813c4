"""Ground-truth geometry of the simulated bench: stereo endoscope and projector.

Conventions are OpenCV's: a point ``X_left`` in the left-camera frame (metres) is
``R @ X_left + T`` in the other device's frame. The right camera sits at ``+B`` along the left
camera's x axis, so ``T_right = (-B, 0, 0)`` for a parallel rig.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of one camera (or a projector seen as an inverse camera)."""

    K: np.ndarray  # 3x3
    dist: np.ndarray  # OpenCV 5-vector (k1, k2, p1, p2, k3)
    width: int
    height: int

    @property
    def f(self) -> float:
        """Focal length in pixels (mean of fx, fy)."""
        return float((self.K[0, 0] + self.K[1, 1]) / 2)

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    def project(
        self, points: np.ndarray, R: np.ndarray | None = None, T: np.ndarray | None = None
    ) -> np.ndarray:
        """Pixel coordinates (N×2) of points (N×3, metres) given in the frame ``R, T`` maps from."""
        R = np.eye(3) if R is None else R
        T = np.zeros(3) if T is None else T
        rvec, _ = cv2.Rodrigues(np.asarray(R, dtype=np.float64))
        uv, _ = cv2.projectPoints(
            np.asarray(points, dtype=np.float64).reshape(-1, 1, 3),
            rvec,
            np.asarray(T, dtype=np.float64),
            self.K,
            self.dist,
        )
        return uv.reshape(-1, 2)


def pinhole(
    width: int,
    height: int,
    hfov_deg: float,
    dist: tuple[float, ...] = (0, 0, 0, 0, 0),
    principal_offset: tuple[float, float] = (0.0, 0.0),
) -> PinholeCamera:
    """A camera of the given size and horizontal field of view, square pixels."""
    f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    K = np.array(
        [
            [f, 0, (width - 1) / 2 + principal_offset[0]],
            [0, f, (height - 1) / 2 + principal_offset[1]],
            [0, 0, 1],
        ],
        dtype=np.float64,
    )
    return PinholeCamera(K=K, dist=np.asarray(dist, dtype=np.float64), width=width, height=height)


def look_at(position: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R, T`` (left-camera frame → device frame) of a device at ``position`` looking at
    ``target``."""
    z = np.asarray(target, float) - np.asarray(position, float)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: device axes expressed in the left-camera frame
    T = -R @ np.asarray(position, float)
    return R, T


@dataclass(frozen=True)
class StereoRig:
    """The bench's true stereo endoscope and projector."""

    left: PinholeCamera
    right: PinholeCamera
    R: np.ndarray  # left → right rotation
    T: np.ndarray  # left → right translation (m)
    projector: PinholeCamera
    R_proj: np.ndarray = field(default_factory=lambda: np.eye(3))  # left → projector
    T_proj: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def baseline_m(self) -> float:
        """Distance between the two camera centres (m)."""
        return float(np.linalg.norm(self.T))


def default_rig(
    width: int = 640,
    height: int = 360,
    baseline_m: float = 0.004,
    working_distance_m: float = 0.06,
    distortion: bool = False,
) -> StereoRig:
    """A 3D-endoscope-like rig: ~70° HFOV, few-mm baseline, projector beside it aimed at the scene.

    With ``distortion`` the two cameras get mild, different radial distortion and slightly
    different principal points, as real endoscope optics have.
    """
    if distortion:
        left = pinhole(width, height, 70.0, (-0.08, 0.02, 0.0005, -0.0003, 0.0), (3.0, -2.0))
        right = pinhole(width, height, 70.0, (-0.07, 0.015, -0.0004, 0.0002, 0.0), (-2.5, 1.5))
    else:
        left = right = pinhole(width, height, 70.0)
    projector = pinhole(1024, 768, 62.0)
    R_proj, T_proj = look_at(
        np.array([-0.012, -0.006, -0.004]), np.array([0.0, 0.0, working_distance_m])
    )
    return StereoRig(
        left=left,
        right=right,
        R=np.eye(3),
        T=np.array([-baseline_m, 0.0, 0.0]),
        projector=projector,
        R_proj=R_proj,
        T_proj=T_proj,
    )


def _camera_to_dict(camera: PinholeCamera) -> dict[str, object]:
    return {
        "K": camera.K.tolist(),
        "dist": camera.dist.tolist(),
        "width": camera.width,
        "height": camera.height,
    }


def _camera_from_dict(d: dict) -> PinholeCamera:
    return PinholeCamera(
        K=np.asarray(d["K"], np.float64),
        dist=np.asarray(d["dist"], np.float64),
        width=int(d["width"]),
        height=int(d["height"]),
    )


def rig_to_dict(rig: StereoRig) -> dict[str, object]:
    """JSON-able description of a rig (inverse: :func:`rig_from_dict`)."""
    return {
        "left": _camera_to_dict(rig.left),
        "right": _camera_to_dict(rig.right),
        "projector": _camera_to_dict(rig.projector),
        "R": np.asarray(rig.R).tolist(),
        "T": np.asarray(rig.T).tolist(),
        "R_proj": np.asarray(rig.R_proj).tolist(),
        "T_proj": np.asarray(rig.T_proj).tolist(),
    }


def rig_from_dict(d: dict) -> StereoRig:
    """The rig a :func:`rig_to_dict` description holds."""
    return StereoRig(
        left=_camera_from_dict(d["left"]),
        right=_camera_from_dict(d["right"]),
        R=np.asarray(d["R"], np.float64),
        T=np.asarray(d["T"], np.float64),
        projector=_camera_from_dict(d["projector"]),
        R_proj=np.asarray(d["R_proj"], np.float64),
        T_proj=np.asarray(d["T_proj"], np.float64),
    )
