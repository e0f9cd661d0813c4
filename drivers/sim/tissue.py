"""Surfaces the bench's cameras look at: planes and a deforming soft-tissue heightfield.

Every surface answers ``hit(origin, dirs)``: where the rays (left-camera frame, see
:mod:`vbfe.drivers.sim.rays`) meet it, the material coordinates there (for the albedo texture,
which moves with the tissue) and the surface normal. Material coordinates are metres in the
surface's rest frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np

from vbfe.drivers.sim.rays import intersect_plane

NEWTON_TOL_M = 3e-8  # ray-surface residual at which Newton stops (float32 resolution ≈ 4e-9 m)


@dataclass
class Hit:
    """Ray-surface intersections, one per ray (H×W float32 arrays)."""

    s: np.ndarray  # ray parameter (depth for the left camera)
    material_x: np.ndarray  # m, rest-frame coordinates of the surface point hit
    material_y: np.ndarray
    normal: np.ndarray  # H×W×3, unit, facing the cameras
    valid: np.ndarray  # bool


class Texture(Protocol):
    """Albedo as a function of material coordinates."""

    def sample(self, material_x: np.ndarray, material_y: np.ndarray) -> np.ndarray:
        """BGR albedo in [0, 1], H×W×3 float32."""


class Surface(Protocol):
    """Anything the ray caster can render."""

    texture: Texture | None

    def hit(self, origin: np.ndarray, dirs: np.ndarray, s0: np.ndarray | None = None) -> Hit:
        """Intersect rays ``origin + s * dirs`` with the surface (``s0``: optional first guess)."""


@dataclass
class ImageTexture:
    """An albedo image laid on the material plane: pixel (0, 0) centre at ``origin_m``."""

    image: np.ndarray  # H×W×3 float32 in [0, 1] (or H×W grey)
    px_per_m: float
    origin_m: tuple[float, float] = (0.0, 0.0)
    border: float = 0.5  # albedo outside the image

    def sample(self, material_x: np.ndarray, material_y: np.ndarray) -> np.ndarray:
        """Bilinear lookup of the albedo at material coordinates."""
        scale = np.float32(self.px_per_m)
        map_x = (material_x - np.float32(self.origin_m[0])) * scale
        map_y = (material_y - np.float32(self.origin_m[1])) * scale
        out = cv2.remap(
            self.image,
            map_x,
            map_y,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=(self.border,) * 3,
        )
        if out.ndim == 2:
            out = cv2.merge([out, out, out])
        return out


@dataclass(frozen=True)
class UniformAlbedo:
    """One albedo everywhere, e.g. plain-coloured silicone (the renderer has a fast path for it)."""

    bgr: tuple[float, float, float] = (0.72, 0.74, 0.95)

    def sample(self, material_x: np.ndarray, material_y: np.ndarray) -> np.ndarray:
        """The constant albedo, broadcast to H×W×3."""
        return np.broadcast_to(np.asarray(self.bgr, np.float32), (*material_x.shape, 3))


def tissue_texture(
    rng: np.random.Generator,
    extent_m: float = 0.2,
    px_per_m: float = 8000.0,
    tint_bgr: tuple[float, float, float] = (0.72, 0.74, 0.95),
) -> ImageTexture:
    """A procedural pinkish tissue albedo: smooth mottling plus a few darker vessel-like lines.

    Covers ``±extent_m / 2`` around the material origin; albedo stays in roughly [0.5, 0.95] so
    the projected pattern dominates the image, as on silicone or tissue.
    """
    n = int(round(extent_m * px_per_m))
    mottle = np.zeros((n, n), np.float32)
    for sigma_m, weight in ((0.004, 0.6), (0.0012, 0.4)):
        noise: np.ndarray = rng.normal(0.0, 1.0, (n, n)).astype(np.float32)
        noise = cv2.GaussianBlur(noise, (0, 0), sigma_m * px_per_m)
        mottle += weight * noise / max(float(noise.std()), 1e-6)
    vessels: np.ndarray = np.zeros((n, n), np.float32)
    for _ in range(6):
        points = rng.uniform(0, n, (5, 2)).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(vessels, [points], False, 1.0, thickness=max(1, int(0.0004 * px_per_m)))
    vessels = cv2.GaussianBlur(vessels, (0, 0), 0.0003 * px_per_m)
    shade = np.clip(0.88 + 0.05 * mottle - 0.25 * vessels, 0.5, 1.0)
    image = np.stack([shade * t for t in tint_bgr], axis=-1).astype(np.float32)
    return ImageTexture(image=image, px_per_m=px_per_m, origin_m=(-extent_m / 2, -extent_m / 2))


@dataclass
class Plane:
    """A flat surface: its ``z = 0`` plane with pose ``R, t`` (plane frame → left camera)."""

    R: np.ndarray
    t: np.ndarray
    texture: Texture | None = None

    def hit(self, origin: np.ndarray, dirs: np.ndarray, s0: np.ndarray | None = None) -> Hit:
        """Analytic ray-plane intersection (``s0`` is not needed)."""
        x, y, s, valid = intersect_plane(origin, dirs, self.R, self.t)
        normal = -np.asarray(self.R, np.float32)[:, 2]
        if float(normal @ (np.asarray(self.t, np.float32) - origin.astype(np.float32))) > 0:
            normal = -normal  # face the camera
        return Hit(
            s=s, material_x=x, material_y=y, normal=np.broadcast_to(normal, dirs.shape), valid=valid
        )


@dataclass(frozen=True)
class MembraneLoad:
    """A point-like pull on the tissue: displacement field ``w(m) = vector · exp(-r²/2a²)``.

    ``contact_m`` is the grasped point in material coordinates, ``vector_m`` the displacement of
    that point (left-camera frame, m) and ``radius_m`` the spread ``a`` of the deformation, which
    grows with tissue thickness and stiffness (see :mod:`vbfe.drivers.sim.mechanics`).
    """

    contact_m: tuple[float, float]
    vector_m: tuple[float, float, float]
    radius_m: float

    def displacement(self, mx: np.ndarray, my: np.ndarray) -> tuple[np.ndarray, ...]:
        """Displacement (dx, dy, dz) in metres of the material points ``mx, my``."""
        r2 = (mx - self.contact_m[0]) ** 2 + (my - self.contact_m[1]) ** 2
        g = np.exp(r2 * np.float32(-0.5 / self.radius_m**2))
        return tuple(g * np.float32(c) for c in self.vector_m)

    def max_lateral_strain(self) -> float:
        """Largest in-plane displacement gradient; must stay < 1 for the field to be invertible."""
        return math.hypot(self.vector_m[0], self.vector_m[1]) / (self.radius_m * math.sqrt(math.e))


@dataclass
class TissueSurface:
    """A soft-tissue (silicone hose) surface seen from above, as a heightfield z(x, y).

    Rest shape: a plane at ``distance_m`` with slopes ``slope``, curved like a hose of radius
    ``hose_radius_m`` (axis along ``hose_axis_deg`` in the x-y plane) plus gentle bumps. A
    :class:`MembraneLoad` displaces material points in 3D; the deformed surface is resampled on
    a grid (``grid_spacing_m``) and rays are intersected with it by Newton iterations.
    """

    distance_m: float = 0.06
    slope: tuple[float, float] = (0.05, -0.08)
    hose_radius_m: float = 0.06
    hose_axis_deg: float = 10.0
    bumps_m: float = 0.0008
    load: MembraneLoad | None = None
    texture: Texture | None = None
    half_extent_m: tuple[float, float] = (0.075, 0.05)
    grid_spacing_m: float = 0.0005
    newton_iterations: int = 10  # at most; stops at NEWTON_TOL_M
    _grid: tuple | None = field(default=None, init=False, repr=False)

    def with_load(self, load: MembraneLoad | None) -> TissueSurface:
        """The same tissue under another load (shares the texture)."""
        return TissueSurface(
            self.distance_m,
            self.slope,
            self.hose_radius_m,
            self.hose_axis_deg,
            self.bumps_m,
            load,
            self.texture,
            self.half_extent_m,
            self.grid_spacing_m,
            self.newton_iterations,
        )

    def rest_height(self, mx: np.ndarray, my: np.ndarray) -> np.ndarray:
        """Depth z (m, left-camera frame) of the undeformed surface at material point (mx, my)."""
        axis = math.radians(self.hose_axis_deg)
        across = -math.sin(axis) * mx + math.cos(axis) * my
        bumps = np.sin(mx * np.float32(2 * math.pi / 0.023) + 0.7) * np.cos(
            my * np.float32(2 * math.pi / 0.031) - 0.3
        )
        return (
            np.float32(self.distance_m)
            + np.float32(self.slope[0]) * mx
            + np.float32(self.slope[1]) * my
            + across * across * np.float32(0.5 / self.hose_radius_m)
            + np.float32(self.bumps_m) * bumps
        )

    def grid(self) -> tuple[np.ndarray, np.ndarray, tuple[float, float, float]]:
        """Deformed heightfield on a spatial grid.

        Returns ``(geometry, material)``: geometry H×W×3 = (z, dz/dx, dz/dy), material H×W×2 =
        rest coordinates of the point now at each grid node, and ``(x0, y0, spacing)``.
        """
        if self._grid is None:
            hx, hy = self.half_extent_m
            h = self.grid_spacing_m
            xs = np.arange(-hx, hx + h / 2, h, dtype=np.float32)
            ys = np.arange(-hy, hy + h / 2, h, dtype=np.float32)
            gx, gy = np.meshgrid(xs, ys)
            mx, my = gx, gy
            dz = np.zeros_like(gx)
            if self.load is not None:
                if self.load.max_lateral_strain() >= 0.9:
                    raise ValueError(
                        f"load {self.load} folds the tissue (lateral strain "
                        f"{self.load.max_lateral_strain():.2f} >= 0.9)"
                    )
                for _ in range(40):  # invert x = m + d(m) by fixed point
                    dx, dy, dz = self.load.displacement(mx, my)
                    new_mx, new_my = gx - dx, gy - dy
                    change = max(float(np.abs(new_mx - mx).max()), float(np.abs(new_my - my).max()))
                    mx, my = new_mx, new_my
                    if change < 1e-8:
                        break
                dz = self.load.displacement(mx, my)[2]
            z = self.rest_height(mx, my) + dz
            dzdy, dzdx = np.gradient(z, h)
            geometry = np.ascontiguousarray(np.stack([z, dzdx, dzdy], axis=-1), np.float32)
            material = np.ascontiguousarray(np.stack([mx, my], axis=-1), np.float32)
            self._grid = (geometry, material, (float(xs[0]), float(ys[0]), h))
        return self._grid

    def _newton(
        self,
        s: np.ndarray,
        bx: np.ndarray,
        by: np.ndarray,
        dz: np.ndarray,
        ax: np.float32,
        ay: np.float32,
        oz: np.float32,
    ) -> tuple:
        """Newton iterations from ``s``: (s, geometry sample, map_x, map_y, residual)."""
        geometry, _, (_, _, h) = self.grid()
        for iteration in range(self.newton_iterations + 1):
            map_x, map_y = s * bx + ax, s * by + ay
            g = cv2.remap(geometry, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            residual = oz + s * dz - g[..., 0]
            if iteration == self.newton_iterations or np.abs(residual).max() < NEWTON_TOL_M:
                break
            slope = dz - (g[..., 1] * bx + g[..., 2] * by) * np.float32(h)
            s = s - residual / slope
        return s, g, map_x, map_y, residual

    def hit(self, origin: np.ndarray, dirs: np.ndarray, s0: np.ndarray | None = None) -> Hit:
        """Newton iterations on ``o_z + s d_z = z(o_xy + s d_xy)`` over the grid, from ``s0``
        (e.g. the previous frame's solution) or from the rest distance."""
        geometry, material, (x0, y0, h) = self.grid()
        inv_h = np.float32(1.0 / h)
        args = (
            dirs[..., 0] * inv_h,
            dirs[..., 1] * inv_h,
            dirs[..., 2],
            np.float32((origin[0] - x0) / h),
            np.float32((origin[1] - y0) / h),
            np.float32(origin[2]),
        )
        cold = (np.float32(self.distance_m) - args[5]) / args[2]
        s, g, map_x, map_y, residual = self._newton(cold if s0 is None else s0, *args)
        if s0 is not None and np.abs(residual).max() >= NEWTON_TOL_M:
            s, g, map_x, map_y, residual = self._newton(cold, *args)
        m = cv2.remap(material, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        rows, cols = geometry.shape[:2]
        valid = (
            (map_x >= 0)
            & (map_x <= cols - 1)
            & (map_y >= 0)
            & (map_y <= rows - 1)
            & (s > 0)
            & (np.abs(residual) < 1e-7)
        )
        normal = np.empty(dirs.shape, np.float32)
        normal[..., 0], normal[..., 1], normal[..., 2] = g[..., 1], g[..., 2], -1.0
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        return Hit(s=s, material_x=m[..., 0], material_y=m[..., 1], normal=normal, valid=valid)
