"""Ray caster: a surface lit by the projector pattern, seen by both cameras, with ground truth.

Per camera pixel: ray → surface point → projector pixel → pattern colour × albedo × Lambertian
shading (+ ambient light) + sensor noise. Shadows cast by the tissue on itself (projector-side
occlusion) are not modelled. The pattern is low-pass filtered to the size of a camera pixel's
footprint on the projector image, so it does not alias.

Speed: the geometry (ray-surface hits, projector coordinates, shading) is smooth over the image,
so it is solved exactly on every ``stride``-th pixel and upsampled bilinearly; only the pattern
and texture lookups run per pixel (``cv2.remap`` on ``uint8``). The left view's ground truth
(depth, disparity, projector coordinates) is solved exactly at every pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.drivers.sim.nuisance import Nuisance, specular_gain
from vbfe.drivers.sim.rays import camera_rays, upsample_strided
from vbfe.drivers.sim.rig import PinholeCamera, StereoRig
from vbfe.drivers.sim.tissue import Hit, Surface, Texture, UniformAlbedo

NOISE_MARGIN_PX = 32  # the noise bank is this much larger than a frame, for random windows


@dataclass
class RenderedPair:
    """Both views and the left view's ground truth."""

    left: np.ndarray  # BGR uint8
    right: np.ndarray
    depth_left_m: np.ndarray  # z in the left-camera frame, float32 (0 where invalid)
    disparity_left_px: np.ndarray  # u_left - u_right of the same surface point, float32
    proj_uv_left: np.ndarray  # H×W×2 projector pixel seen at each left pixel
    valid_left: np.ndarray  # bool: the left pixel sees the surface


def project_points(
    camera: PinholeCamera,
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    R: np.ndarray | None = None,
    T: np.ndarray | None = None,
) -> np.ndarray:
    """Pixel coordinates (…×2, dtype of ``x``) of points given as coordinate arrays (left frame)."""
    dtype = x.dtype
    if R is not None:
        Rd, Td = np.asarray(R, dtype), np.asarray(T, dtype)
        x, y, z = (Rd[i, 0] * x + Rd[i, 1] * y + Rd[i, 2] * z + Td[i] for i in range(3))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = 1 / z
    if np.any(camera.dist != 0):
        pts = np.stack([x * inv_z, y * inv_z, np.ones_like(z)], axis=-1).reshape(-1, 1, 3)
        uv, _ = cv2.projectPoints(
            pts.astype(np.float64), np.zeros(3), np.zeros(3), camera.K, camera.dist
        )
        return uv.reshape(*x.shape, 2).astype(dtype)
    K = np.asarray(camera.K, dtype)
    uv = np.empty((*x.shape, 2), dtype)
    uv[..., 0] = x * inv_z * K[0, 0] + K[0, 2]
    uv[..., 1] = y * inv_z * K[1, 1] + K[1, 2]
    return uv


def pattern_blur_px(rig: StereoRig, distance_m: float) -> float:
    """Gaussian σ (projector pixels) matching one left-camera pixel's footprint at
    ``distance_m``."""
    camera_px_m = distance_m / rig.left.f
    projector_px_m = (distance_m + float(np.linalg.norm(rig.T_proj))) / rig.projector.f
    return max(0.0, 0.5 * (camera_px_m / projector_px_m) - 0.3)


def _default_stride(camera: PinholeCamera) -> int:
    """About 160 coarse columns: geometry interpolation error stays < 0.05 projector pixels."""
    return next(
        k
        for k in (8, 4, 2, 1)
        if camera.width % k == 0 and camera.height % k == 0 and (camera.width // k >= 160 or k == 1)
    )


@dataclass
class _Eye:
    camera: PinholeCamera
    R: np.ndarray | None
    T: np.ndarray | None
    map_buffer: np.ndarray | None = None
    gain_buffer: np.ndarray | None = None
    last_s: np.ndarray | None = None  # previous coarse solution: Newton's warm start


class StereoRenderer:
    """Renders both eyes of ``rig`` looking at surfaces lit by the current projector pattern.

    Keeps the cached rays, the prepared pattern, a bank of sensor noise and the output buffers
    between frames, so a bench camera can render a stream quickly. ``nuisance`` adds what real
    tissue and optics do to the pattern (:mod:`vbfe.drivers.sim.nuisance`).
    """

    def __init__(
        self,
        rig: StereoRig,
        ambient: float = 0.15,
        noise_sigma: float = 1.0,
        shading: bool = True,
        stride: int | None = None,
        rng: np.random.Generator | None = None,
        nuisance: Nuisance | None = None,
    ) -> None:
        self.rig = rig
        self.nuisance = nuisance or Nuisance()
        self._distance_m = 0.06
        self.ambient = float(ambient)
        self.shading = shading
        self.stride = _default_stride(rig.left) if stride is None else stride
        self.rng = np.random.default_rng() if rng is None else rng
        self._eyes = (_Eye(rig.left, None, None), _Eye(rig.right, rig.R, rig.T))
        shape = (rig.left.height + NOISE_MARGIN_PX, rig.left.width + NOISE_MARGIN_PX, 3)
        noise = np.clip(self.rng.normal(0.0, noise_sigma, shape), -4 * noise_sigma, 4 * noise_sigma)
        self._noise = np.rint(noise).astype(np.int16)  # clipped at ±4σ
        self._offset_banks: dict[tuple[float, ...], tuple[np.ndarray, np.ndarray | None]] = {}
        self._pattern: np.ndarray | None = None

    def set_pattern(
        self, pattern_bgr: np.ndarray, blur_sigma_px: float | None = None, distance_m: float = 0.06
    ) -> None:
        """The projector image (BGR or grey ``uint8``), low-passed against aliasing."""
        if blur_sigma_px is None:
            blur_sigma_px = pattern_blur_px(self.rig, distance_m)
        pattern = (
            pattern_bgr if pattern_bgr.ndim == 3 else cv2.cvtColor(pattern_bgr, cv2.COLOR_GRAY2BGR)
        )
        pattern = self.nuisance.projector_image(pattern)
        self._distance_m = distance_m
        if blur_sigma_px > 0:
            pattern = cv2.GaussianBlur(pattern, (0, 0), blur_sigma_px)
        self._pattern = np.ascontiguousarray(pattern, np.uint8)

    def _coarse(
        self, eye: _Eye, surface: Surface
    ) -> tuple[Hit, np.ndarray, np.ndarray, np.ndarray | None]:
        """Hits, projector coordinates, light gain (uint8 BGR) and specular gain (float32, None
        without highlights) on the strided grid."""
        origin, dirs = camera_rays(eye.camera, eye.R, eye.T, stride=self.stride)
        hit = surface.hit(origin, dirs, eye.last_s)
        eye.last_s = hit.s
        x, y, z = _points(origin, dirs, hit.s)
        proj_uv = project_points(self.rig.projector, x, y, z, self.rig.R_proj, self.rig.T_proj)
        gain = np.where(hit.valid, np.float32(1.0), np.float32(0.0))
        if self.shading:
            centre = (-np.asarray(self.rig.R_proj).T @ np.asarray(self.rig.T_proj)).astype(
                np.float32
            )
            lx, ly, lz = centre[0] - x, centre[1] - y, centre[2] - z
            cos = hit.normal[..., 0] * lx + hit.normal[..., 1] * ly + hit.normal[..., 2] * lz
            gain *= np.maximum(cos / np.sqrt(lx * lx + ly * ly + lz * lz), 0)
        specular = None
        if self.shading and self.nuisance.specular > 0:
            # highlights of the projector (in its pattern's colour) and of the endoscope's white
            # light at the tip, midway between the eyes (scaled by the ambient level)
            points = np.stack([x, y, z], axis=-1)
            to_eye = origin.astype(np.float32) - points
            tip = (-0.5 * np.asarray(self.rig.R).T @ np.asarray(self.rig.T)).astype(np.float32)
            specular = (
                np.stack(
                    [
                        specular_gain(hit.normal, source - points, to_eye, self.nuisance)
                        for source in (centre, tip)
                    ],
                    axis=-1,
                )
                * hit.valid[..., None]
            )
        tint = np.asarray(_uniform_bgr(surface.texture) or (1.0, 1.0, 1.0), np.float32)
        gain_bgr = gain[..., None] * (tint * np.float32(255 * (1 - self.ambient)))
        return hit, proj_uv, np.clip(gain_bgr + 0.5, 0, 255).astype(np.uint8), specular

    def render_eye(self, index: int, surface: Surface) -> np.ndarray:
        """One view (0 = left, 1 = right) as BGR ``uint8``."""
        if self._pattern is None:
            raise ValueError("no projector pattern set; call set_pattern first")
        eye = self._eyes[index]
        k = self.stride
        hit, proj_uv, gain, specular = self._coarse(eye, surface)
        proj_map = upsample_strided(proj_uv, k, eye.map_buffer)
        eye.map_buffer = proj_map.base if proj_map.base is not None else proj_map
        light = cv2.remap(
            self._pattern,
            proj_map,
            None,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=(0, 0, 0),
        )
        light = self.nuisance.surface_light(light, eye.camera.f / (1e3 * self._distance_m))
        gain_full = upsample_strided(gain, k, eye.gain_buffer)
        eye.gain_buffer = gain_full.base if gain_full.base is not None else gain_full
        image = cv2.multiply(light, gain_full, scale=1 / 255)
        uniform = _uniform_bgr(surface.texture)
        ambient = 255 * self.ambient
        if uniform is not None or surface.texture is None:
            offset = tuple(ambient * c for c in (uniform or (1.0, 1.0, 1.0)))
        else:
            material = np.ascontiguousarray(
                upsample_strided(np.dstack([hit.material_x, hit.material_y]), k)
            )
            albedo = surface.texture.sample(material[..., 0], material[..., 1])
            image = np.clip(
                (image.astype(np.float32) + np.float32(ambient)) * albedo + 0.5, 0, 255
            ).astype(np.uint8)
            offset = (0.0, 0.0, 0.0)
        if specular is not None:  # mirrored light: no albedo, saturates the sensor
            projector, tip = cv2.split(np.ascontiguousarray(upsample_strided(specular, k)))
            image = cv2.add(image, cv2.multiply(light, cv2.merge([projector] * 3), dtype=cv2.CV_8U))
            image = cv2.add(
                image, cv2.merge([tip * np.float32(255 * self.ambient)] * 3), dtype=cv2.CV_8U
            )
        if self.nuisance.affects_camera:
            image = self.nuisance.camera(cv2.add(image, offset + (0.0,)))
            offset = (0.0, 0.0, 0.0)
        return self._add_offset_and_noise(image, offset)

    def _add_offset_and_noise(self, image: np.ndarray, offset_bgr: tuple[float, ...]) -> np.ndarray:
        """``image + offset + noise`` saturated to ``uint8``, from a random window of a noise
        bank split into positive and negative ``uint8`` parts (two fast saturating adds)."""
        if offset_bgr not in self._offset_banks:
            total = self._noise + np.rint(np.asarray(offset_bgr)).astype(np.int16)
            negative = np.clip(-total, 0, 255).astype(np.uint8)
            self._offset_banks[offset_bgr] = (
                np.clip(total, 0, 255).astype(np.uint8),
                negative if negative.any() else None,
            )
        positive, negative = self._offset_banks[offset_bgr]
        oy, ox = self.rng.integers(0, NOISE_MARGIN_PX, 2)
        h, w = image.shape[:2]
        image = cv2.add(image, positive[oy : oy + h, ox : ox + w])
        if negative is not None:
            image = cv2.subtract(image, negative[oy : oy + h, ox : ox + w])
        return image

    def render(self, surface: Surface) -> tuple[np.ndarray, np.ndarray]:
        """Both views as BGR ``uint8``."""
        return self.render_eye(0, surface), self.render_eye(1, surface)

    def truth(self, surface: Surface) -> dict[str, np.ndarray]:
        """Exact per-pixel truth of the left view: depth, disparity, projector coordinates."""
        rig = self.rig
        coarse = self._coarse(self._eyes[0], surface)[0]
        origin, dirs = camera_rays(rig.left)
        s0 = np.ascontiguousarray(upsample_strided(coarse.s, self.stride))
        hit = surface.hit(origin, dirs, s0)
        x, y, z = _points(origin, dirs.astype(np.float64), hit.s.astype(np.float64))
        valid = hit.valid & (z > 0)
        proj_uv = project_points(rig.projector, x, y, z, rig.R_proj, rig.T_proj).astype(np.float32)
        uv_right = project_points(rig.right, x, y, z, rig.R, rig.T)
        u_left = np.arange(rig.left.width, dtype=np.float64)[None, :]
        return {
            "depth_left_m": np.where(valid, z, 0).astype(np.float32),
            "disparity_left_px": np.where(valid, u_left - uv_right[..., 0], 0).astype(np.float32),
            "proj_uv_left": proj_uv,
            "valid_left": valid,
        }


def _points(origin: np.ndarray, dirs: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, ...]:
    return tuple(s.dtype.type(origin[i]) + s * dirs[..., i] for i in range(3))


def _uniform_bgr(texture: Texture | None) -> tuple[float, float, float] | None:
    return texture.bgr if isinstance(texture, UniformAlbedo) else None


@dataclass
class _Retextured:
    """A surface seen with another albedo."""

    base: Surface
    texture: Texture | None

    def hit(self, origin: np.ndarray, dirs: np.ndarray, s0: np.ndarray | None = None) -> Hit:
        return self.base.hit(origin, dirs, s0)


def render_scene(
    rig: StereoRig,
    surface: Surface,
    pattern_bgr: np.ndarray,
    texture: Texture | None = None,
    ambient: float = 0.15,
    noise_sigma: float = 1.0,
    rng: np.random.Generator | None = None,
    shading: bool = True,
    pattern_blur: float | None = None,
    nuisance: Nuisance | None = None,
) -> RenderedPair:
    """Render ``surface`` lit by ``pattern_bgr`` (projector image, ``uint8``) in both cameras.

    ``texture`` overrides the surface's albedo; ``ambient`` is the fraction of light not from the
    projector; ``noise_sigma`` Gaussian sensor noise in grey levels; ``pattern_blur`` the
    anti-alias σ in projector pixels (default: a camera pixel's footprint at the surface's
    distance). The truth is for the left view; disparity is ``u_left − u_right`` of the same
    surface point, i.e. ``f·B/z`` for a parallel rig without distortion. ``nuisance`` degrades
    the images (not the truth) as real tissue and optics do.
    """
    renderer = StereoRenderer(
        rig, ambient=ambient, noise_sigma=noise_sigma, shading=shading, rng=rng, nuisance=nuisance
    )
    renderer.set_pattern(pattern_bgr, pattern_blur, float(getattr(surface, "distance_m", 0.06)))
    if texture is not None:
        surface = _Retextured(surface, texture)
    left, right = renderer.render(surface)
    truth = renderer.truth(surface)
    return RenderedPair(left=left, right=right, **truth)
