"""How well a calibration is known across the image (mrcal's idea, first order): the joint
stereo solve's covariance propagated to depth uncertainty at the working distance, and where
the board was seen.

The covariance of the solve's global parameters (both cameras' intrinsics, the left→right
rotation and translation) is ``σ² (JᵀJ)⁻¹`` of the stereo reprojection problem with every
view's board pose marginalised out (Schur complement), ``σ²`` the per-coordinate residual
variance. A point at the working distance seen at pixel ``q`` of the left image is projected
into the right image; the depth triangulated from that pixel pair changes with the parameters
as ``J_z`` (central differences), and ``σ_z² = J_z Σ J_zᵀ``: correlated errors (a principal
point shift absorbed by the rotation) cancel as they do in the solve. Pixel noise of the
matches themselves is not included (that is ``z²/(f·B)`` per px of disparity error).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.calib.camera import CameraFit

_GRID = (16, 12)  # samples across the image, x by y
REGIONS = (3, 3)  # board coverage: columns by rows
_REGION_NAMES = (
    ("top-left", "top", "top-right"),
    ("left", "centre", "right"),
    ("bottom-left", "bottom", "bottom-right"),
)


def _intrinsic_columns(n_dist: int, fixed_k3: bool) -> np.ndarray:
    """Columns of projectPoints' jacobian (rvec 3, tvec 3, f 2, c 2, distortion) that are
    intrinsics solved for."""
    cols = list(range(6, 10 + n_dist))
    if fixed_k3 and n_dist >= 5:
        cols.remove(10 + 4)
    return np.asarray(cols)


@dataclass
class StereoSolve:
    """What the joint stereo solve left: both cameras, left→right pose, and per view the left
    camera's board pose with the corners seen by both eyes."""

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    rvecs: list[np.ndarray]
    tvecs: list[np.ndarray]
    object_points: list[np.ndarray]  # per view, n×3
    left_px: list[np.ndarray]  # per view, n×2
    right_px: list[np.ndarray]


def _global(solve: StereoSolve, cols: np.ndarray) -> np.ndarray:
    """The solved global parameters: left intrinsics, right intrinsics, rvec(R), T."""

    def intrinsics(K: np.ndarray, D: np.ndarray) -> np.ndarray:
        return np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], D][cols - 6]

    return np.r_[
        intrinsics(solve.K1, solve.D1),
        intrinsics(solve.K2, solve.D2),
        cv2.Rodrigues(solve.R)[0].reshape(3),
        solve.T.reshape(3),
    ]


def _unpack(theta: np.ndarray, solve: StereoSolve, cols: np.ndarray):
    n = len(cols)

    def camera(values: np.ndarray, K: np.ndarray, D: np.ndarray):
        full = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], D]
        full[cols - 6] = values
        return (np.array([[full[0], 0, full[2]], [0, full[1], full[3]], [0, 0, 1.0]]), full[4:])

    K1, D1 = camera(theta[:n], solve.K1, solve.D1)
    K2, D2 = camera(theta[n : 2 * n], solve.K2, solve.D2)
    return K1, D1, K2, D2, cv2.Rodrigues(theta[2 * n : 2 * n + 3])[0], theta[2 * n + 3 :]


def joint_covariance(solve: StereoSolve, fixed_k3: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the global parameters of the joint stereo solve (both cameras'
    intrinsics, rvec(R), T), the board poses marginalised out; and the jacobian columns the
    intrinsics are."""
    cols = _intrinsic_columns(len(solve.D1), fixed_k3)
    n = len(cols)
    n_global = 2 * n + 6
    information = np.zeros((n_global, n_global))
    rvec_rt = cv2.Rodrigues(solve.R)[0]
    squares, count = 0.0, 0
    for obj, left, right, rvec, tvec in zip(
        solve.object_points, solve.left_px, solve.right_px, solve.rvecs, solve.tvecs, strict=False
    ):
        obj = obj.reshape(-1, 1, 3).astype(np.float64)
        proj_l, jac_l = cv2.projectPoints(obj, rvec, tvec, solve.K1, solve.D1)
        r3, t3, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = cv2.composeRT(
            rvec, tvec, rvec_rt, solve.T.reshape(3, 1)
        )
        proj_r, jac_r = cv2.projectPoints(obj, r3, t3, solve.K2, solve.D2)
        squares += float(
            np.sum((proj_l.reshape(-1, 2) - left) ** 2)
            + np.sum((proj_r.reshape(-1, 2) - right) ** 2)
        )
        count += left.size + right.size
        d_view = np.block([[dr3dr1, dr3dt1], [dt3dr1, dt3dt1]])
        d_rt = np.block([[dr3dr2, dr3dt2], [dt3dr2, dt3dt2]])
        rows = len(obj) * 2
        J_g = np.zeros((2 * rows, n_global))
        J_g[:rows, :n] = jac_l[:, cols]
        J_g[rows:, n : 2 * n] = jac_r[:, cols]
        J_g[rows:, 2 * n :] = jac_r[:, :6] @ d_rt
        J_p = np.vstack([jac_l[:, :6], jac_r[:, :6] @ d_view])
        H_gp = J_g.T @ J_p
        information += J_g.T @ J_g - H_gp @ np.linalg.solve(J_p.T @ J_p, H_gp.T)
    variance = squares / max(count - n_global - 6 * len(solve.rvecs), 1)
    return variance * np.linalg.pinv(information), cols


def _depths(
    theta: np.ndarray,
    solve: StereoSolve,
    cols: np.ndarray,
    left_px: np.ndarray,
    right_px: np.ndarray,
) -> np.ndarray:
    """Depth (m, left frame) of each pixel pair triangulated with parameters ``theta``
    (midpoint of the two rays)."""
    K1, D1, K2, D2, R, T = _unpack(theta, solve, cols)
    ray_l = cv2.undistortPoints(left_px.reshape(-1, 1, 2), K1, D1).reshape(-1, 2)
    ray_r = cv2.undistortPoints(right_px.reshape(-1, 1, 2), K2, D2).reshape(-1, 2)
    d1 = np.column_stack([ray_l, np.ones(len(ray_l))])
    d2 = np.column_stack([ray_r, np.ones(len(ray_r))]) @ R  # Rᵀ·ray, row-wise
    c2 = -R.T @ T.reshape(3)
    # closest points c1 + a·d1 and c2 + b·d2 (c1 = 0)
    a11, a12, a22 = (d1 * d1).sum(1), -(d1 * d2).sum(1), (d2 * d2).sum(1)
    b1, b2 = d1 @ c2, -(d2 @ c2)
    det = a11 * a22 - a12 * a12
    a = (b1 * a22 - a12 * b2) / det
    b = (a11 * b2 - a12 * b1) / det
    return (a * d1[:, 2] + c2[2] + b * d2[:, 2]) / 2


@dataclass
class UncertaintyMap:
    """Depth σ (m) on a grid of left-image pixels at the working distance, and the board's
    coverage per image region."""

    u: np.ndarray  # (gy, gx) pixel x
    v: np.ndarray  # (gy, gx) pixel y
    depth_sigma_m: np.ndarray  # (gy, gx)
    working_distance_m: float
    coverage: np.ndarray  # (3, 3) views with board corners in each region (left eye)

    def summary(self) -> str:
        """One line: depth σ at the centre and the corners, regions without any board view."""
        gy, gx = self.depth_sigma_m.shape
        centre = float(self.depth_sigma_m[gy // 2, gx // 2])
        corners = float(np.max(self.depth_sigma_m[[0, 0, -1, -1], [0, -1, 0, -1]]))
        empty = [
            _REGION_NAMES[r][c]
            for r in range(REGIONS[1])
            for c in range(REGIONS[0])
            if self.coverage[r, c] == 0
        ]
        return (
            f"depth σ at {self.working_distance_m * 1e3:.0f} mm: {centre * 1e3:.3f} mm "
            f"centre, {corners * 1e3:.3f} mm corners; "
            + (
                f"no board seen in the {', '.join(empty)}"
                if empty
                else "board seen in every region"
            )
        )


def board_coverage(fit: CameraFit, image_size: tuple[int, int]) -> np.ndarray:
    """Views (rows × columns of :data:`REGIONS`) with at least one corner in each region."""
    w, h = image_size
    counts = np.zeros((REGIONS[1], REGIONS[0]), int)
    for det in fit.detections:
        col = np.clip((det.corners[:, 0] * REGIONS[0] / w).astype(int), 0, REGIONS[0] - 1)
        row = np.clip((det.corners[:, 1] * REGIONS[1] / h).astype(int), 0, REGIONS[1] - 1)
        seen = np.zeros_like(counts, bool)
        seen[row, col] = True
        counts += seen
    return counts


def uncertainty_map(
    cal: Calibration,
    solve: StereoSolve,
    left: CameraFit,
    working_distance_m: float,
    fixed_k3: bool = False,
) -> UncertaintyMap:
    """Depth σ over the left image at ``working_distance_m`` (see the module)."""
    w, h = cal.image_size
    u, v = np.meshgrid(np.linspace(0, w - 1, _GRID[0]), np.linspace(0, h - 1, _GRID[1]))
    left_px = np.column_stack([u.ravel(), v.ravel()])
    rays = cv2.undistortPoints(left_px.reshape(-1, 1, 2), solve.K1, solve.D1).reshape(-1, 2)
    points = np.column_stack([rays, np.ones(len(rays))]) * working_distance_m
    right_px, _ = cv2.projectPoints(
        points.reshape(-1, 1, 3),
        cv2.Rodrigues(solve.R)[0],
        solve.T.reshape(3, 1),
        solve.K2,
        solve.D2,
    )
    right_px = right_px.reshape(-1, 2)
    cov, cols = joint_covariance(solve, fixed_k3)
    theta = _global(solve, cols)
    J = np.empty((len(left_px), len(theta)))
    for k in range(len(theta)):  # central differences of the triangulated depth
        step = 1e-6 * max(abs(theta[k]), 1e-3)
        plus, minus = theta.copy(), theta.copy()
        plus[k] += step
        minus[k] -= step
        J[:, k] = (
            _depths(plus, solve, cols, left_px, right_px)
            - _depths(minus, solve, cols, left_px, right_px)
        ) / (2 * step)
    sigma_z = np.sqrt(np.einsum("ij,jk,ik->i", J, cov, J))
    return UncertaintyMap(
        u, v, sigma_z.reshape(u.shape), working_distance_m, board_coverage(left, cal.image_size)
    )
