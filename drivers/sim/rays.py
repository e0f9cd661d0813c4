"""Viewing rays of the bench's cameras, for inverse-mapping renderers.

A camera pixel is undistorted exactly (iterative inverse of OpenCV's distortion model) into a
ray; rays are expressed in the left-camera frame as ``origin + s * direction``. Rays are cached
per camera because they depend only on the intrinsics.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from vbfe.drivers.sim.rig import PinholeCamera

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@lru_cache(maxsize=32)
def _normalized_rays(
    K_bytes: bytes, dist_bytes: bytes, xs: tuple[float, float, int], ys: tuple[float, float, int]
) -> np.ndarray:
    K = np.frombuffer(K_bytes, dtype=np.float64).reshape(3, 3)
    dist = np.frombuffer(dist_bytes, dtype=np.float64)
    u = xs[0] + xs[1] * np.arange(xs[2], dtype=np.float64)
    v = ys[0] + ys[1] * np.arange(ys[2], dtype=np.float64)
    uu, vv = np.meshgrid(u, v)
    pix = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
    if np.any(dist != 0):
        xy = cv2.undistortPoints(pix, K, dist, criteria=_UNDISTORT_CRITERIA).reshape(-1, 2)
    else:
        xy = (pix.reshape(-1, 2) - K[:2, 2]) / np.diag(K)[:2]
    rays = np.empty((ys[2], xs[2], 3), dtype=np.float32)
    rays[..., 0] = xy[:, 0].reshape(ys[2], xs[2])
    rays[..., 1] = xy[:, 1].reshape(ys[2], xs[2])
    rays[..., 2] = 1.0
    rays.flags.writeable = False
    return rays


def _axis(n: int, supersample: int, stride: int) -> tuple[float, float, int]:
    """(first pixel coordinate, step, count) of the sample positions along one image axis."""
    if stride > 1:
        # block centres, padded by one block each side: cv2.resize by ``stride`` of these
        # samples, cropped by ``stride``, lands exactly on every pixel centre
        return ((stride - 1) / 2 - stride, float(stride), n // stride + 2)
    return (0.5 / supersample - 0.5, 1.0 / supersample, n * supersample)


def camera_rays(
    camera: PinholeCamera,
    R: np.ndarray | None = None,
    T: np.ndarray | None = None,
    supersample: int = 1,
    stride: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Ray ``origin`` (3,) and ``directions`` (rows × cols × 3, float32) in the left-camera frame.

    ``R, T`` map left-camera coordinates into this camera's frame (identity for the left
    camera). Directions have unit z in the camera's own frame, so for the left camera the ray
    parameter equals the depth. ``supersample`` s > 1 gives s×s rays per pixel (for
    anti-aliasing by block averaging); ``stride`` k > 1 gives one ray per k×k block plus one
    block of padding around the image (see :func:`upsample_strided`); the image size must be
    divisible by k.
    """
    if stride > 1 and (camera.width % stride or camera.height % stride):
        raise ValueError(f"image size {camera.width}x{camera.height} not divisible by {stride}")
    rays = _normalized_rays(
        np.ascontiguousarray(camera.K, np.float64).tobytes(),
        np.ascontiguousarray(camera.dist, np.float64).tobytes(),
        _axis(camera.width, supersample, stride),
        _axis(camera.height, supersample, stride),
    )
    if R is None or np.allclose(R, np.eye(3)):
        dirs = rays
    else:
        dirs = (rays.reshape(-1, 3) @ np.asarray(R, np.float32)).reshape(rays.shape)
    origin = np.zeros(3) if T is None else -np.asarray(R if R is not None else np.eye(3)).T @ T
    return origin.astype(np.float64), dirs


def upsample_strided(field: np.ndarray, stride: int, out: np.ndarray | None = None) -> np.ndarray:
    """Bilinear full-resolution view of a field sampled on :func:`camera_rays`' strided grid.

    ``out`` (padded size, reused between calls) avoids reallocating large buffers.
    """
    if stride == 1:  # sampled on every pixel already, without padding
        return field
    rows, cols = field.shape[:2]
    size = (cols * stride, rows * stride)
    out = cv2.resize(field, size, dst=out, interpolation=cv2.INTER_LINEAR)
    return out[stride:-stride, stride:-stride]


def intersect_plane(
    origin: np.ndarray, dirs: np.ndarray, R_plane: np.ndarray, t_plane: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where rays hit the plane ``z = 0`` of a frame with pose ``R_plane, t_plane`` (frame → left).

    Returns the plane coordinates ``x, y`` (m, H×W float32), the ray parameter ``s`` and a mask
    of rays that hit the plane in front of the camera.
    """
    R_plane = np.asarray(R_plane, np.float64)
    t_plane = np.asarray(t_plane, np.float64).reshape(3)
    normal = R_plane[:, 2]
    denom = dirs @ normal.astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.float32(normal @ (t_plane - origin)) / denom
    valid = np.isfinite(s) & (s > 0)
    s = np.where(valid, s, 0).astype(np.float32)
    # plane coordinates: R_plane^T (origin + s d - t_plane)
    rel0 = (R_plane.T @ (origin - t_plane)).astype(np.float32)
    Rt = R_plane.T.astype(np.float32)
    d_local_x = dirs @ Rt[0]
    d_local_y = dirs @ Rt[1]
    x = rel0[0] + s * d_local_x
    y = rel0[1] + s * d_local_y
    return x, y, s, valid
