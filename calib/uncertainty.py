"""How well a calibration is known across the image (mrcal's idea, first order): the solve's
covariance propagated to projection and depth uncertainty at the working distance, and where
the board was seen.

Each camera's intrinsics covariance is ``σ² (JᵀJ)⁻¹`` of its board solve, the board poses
marginalised out (Schur complement), ``σ²`` the per-coordinate residual variance. A point at
the working distance seen at pixel ``q`` of the left image projects into each eye with a
covariance ``J_q Σ J_qᵀ``; the disparity error is the two eyes' x errors together, and the depth
error ``z²/(f·B) · σ_d`` combined with the baseline's ``z · σ_B / B``. Unlike mrcal, the
camera frame's own shift under intrinsics changes is not compensated, so this errs on the
side of more uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.calib.board import BoardSpec
from vbfe.calib.calibration import Calibration
from vbfe.calib.camera import CameraFit

_GRID = (16, 12)  # samples across the image, x by y
REGIONS = (3, 3)  # board coverage: columns by rows
_REGION_NAMES = (("top-left", "top", "top-right"), ("left", "centre", "right"),
                 ("bottom-left", "bottom", "bottom-right"))


def _intrinsic_columns(n_dist: int, fixed_k3: bool) -> np.ndarray:
    """Columns of projectPoints' jacobian (rvec 3, tvec 3, f 2, c 2, distortion) that are
    intrinsics solved for."""
    cols = list(range(6, 10 + n_dist))
    if fixed_k3 and n_dist >= 5:
        cols.remove(10 + 4)
    return np.asarray(cols)


def intrinsics_covariance(spec: BoardSpec, fit: CameraFit, fixed_k3: bool = False
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the solved intrinsics (fx, fy, cx, cy, distortion) and the jacobian
    columns they are; the board poses marginalised out."""
    cols = _intrinsic_columns(len(fit.D), fixed_k3)
    n = len(cols)
    information = np.zeros((n, n))
    squares, count = 0.0, 0
    board = spec.object_points()
    for det, rvec, tvec in zip(fit.detections, fit.rvecs, fit.tvecs):
        obj = board[det.ids].reshape(-1, 1, 3)
        proj, jac = cv2.projectPoints(obj, rvec, tvec, fit.K, fit.D)
        squares += float(np.sum((proj.reshape(-1, 2) - det.corners) ** 2))
        count += det.corners.size
        J_i, J_e = jac[:, cols], jac[:, :6]
        H_ie = J_i.T @ J_e
        information += J_i.T @ J_i - H_ie @ np.linalg.solve(J_e.T @ J_e, H_ie.T)
    variance = squares / max(count - n, 1)
    return variance * np.linalg.pinv(information), cols


def _projection_sigma(points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, K: np.ndarray,
                      D: np.ndarray, cov: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """σ (px) of the x coordinate of each point's projection (n)."""
    _, jac = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, tvec, K, D)
    J = jac[:, cols].reshape(-1, 2, len(cols))[:, 0, :]
    return np.sqrt(np.einsum("ij,jk,ik->i", J, cov, J))


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
        empty = [_REGION_NAMES[r][c] for r in range(REGIONS[1]) for c in range(REGIONS[0])
                 if self.coverage[r, c] == 0]
        return (f"depth σ at {self.working_distance_m * 1e3:.0f} mm: {centre * 1e3:.3f} mm "
                f"centre, {corners * 1e3:.3f} mm corners; "
                + (f"no board seen in the {', '.join(empty)}" if empty
                   else "board seen in every region"))


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


def uncertainty_map(cal: Calibration, spec: BoardSpec, left: CameraFit, right: CameraFit,
                    working_distance_m: float, sigma_B_m: float,
                    fixed_k3: bool = False) -> UncertaintyMap:
    """Depth σ over the left image at ``working_distance_m`` (see the module)."""
    w, h = cal.image_size
    u, v = np.meshgrid(np.linspace(0, w - 1, _GRID[0]), np.linspace(0, h - 1, _GRID[1]))
    rays = cv2.undistortPoints(np.column_stack([u.ravel(), v.ravel()]).reshape(-1, 1, 2),
                               cal.K1, cal.D1).reshape(-1, 2)
    points = np.column_stack([rays, np.ones(len(rays))]) * working_distance_m
    zero = np.zeros(3)
    sigma_x = []
    for fit, (rvec, tvec) in ((left, (zero, zero)),
                              (right, (cv2.Rodrigues(cal.R)[0].reshape(3), cal.T))):
        cov, cols = intrinsics_covariance(spec, fit, fixed_k3)
        sigma_x.append(_projection_sigma(points, rvec, tvec, fit.K, fit.D, cov, cols))
    sigma_d = np.hypot(*sigma_x)
    z = working_distance_m
    sigma_z = np.hypot(z * z / (cal.f * cal.B) * sigma_d, z * sigma_B_m / cal.B)
    return UncertaintyMap(u, v, sigma_z.reshape(u.shape), z, board_coverage(left, cal.image_size))
