"""The ray caster: images agree with their own ground truth."""

import cv2
import numpy as np
import pytest

from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import MembraneLoad, Plane, TissueSurface, UniformAlbedo


def smooth_pattern() -> np.ndarray:
    """A colourful projector image that varies slowly enough to compare pixel values exactly."""
    v, u = np.mgrid[0:768, 0:1024].astype(np.float32)
    return np.dstack(
        [128 + 100 * np.sin(u / 40), 128 + 100 * np.cos(v / 35), 128 + 100 * np.sin((u + v) / 50)]
    ).astype(np.uint8)


@pytest.fixture(scope="module")
def tissue() -> TissueSurface:
    return TissueSurface(load=MembraneLoad((0.004, 0.002), (0.005, 0.002, -0.006), 0.015))


@pytest.fixture(scope="module")
def rendered(tissue):
    return render_scene(
        default_rig(320, 180),
        tissue,
        smooth_pattern(),
        ambient=0.0,
        noise_sigma=1.0,
        shading=False,
        pattern_blur=0.0,
        rng=np.random.default_rng(0),
    )


def test_disparity_triangulates_to_depth(rendered):
    rig = default_rig(320, 180)
    valid = rendered.valid_left
    assert valid.mean() > 0.99
    depth = rig.left.f * rig.baseline_m / rendered.disparity_left_px[valid].astype(np.float64)
    assert np.abs(depth / rendered.depth_left_m[valid] - 1).max() < 1e-6
    assert 0.045 < rendered.depth_left_m[valid].min() < rendered.depth_left_m.max() < 0.09


def test_left_colour_is_the_pattern_at_the_true_projector_pixel(rendered):
    pattern = smooth_pattern().astype(np.float32)
    uv = rendered.proj_uv_left
    expected = cv2.remap(pattern, uv, None, cv2.INTER_LINEAR)
    inside = (
        rendered.valid_left
        & (uv[..., 0] > 1)
        & (uv[..., 0] < 1022)
        & (uv[..., 1] > 1)
        & (uv[..., 1] < 766)
    )
    assert inside.mean() > 0.8  # the projector lights most of the view
    diff = rendered.left.astype(np.float32)[inside] - expected[inside]
    assert abs(diff.mean()) < 0.2 and 0.8 < diff.std() < 1.3  # only the sensor noise (σ = 1)


def test_right_view_sees_the_same_surface_points(rendered):
    """A left pixel and the pixel `disparity` to its left in the right view show the same colour."""
    rows, cols = np.mgrid[20:160:7, 60:300:7]
    u_right = cols - rendered.disparity_left_px[rows, cols]
    right = rendered.right.astype(np.float32)
    sampled = cv2.remap(
        right, u_right.astype(np.float32), rows.astype(np.float32), cv2.INTER_LINEAR
    )
    diff = sampled - rendered.left.astype(np.float32)[rows, cols]
    assert np.abs(diff).mean() < 2.0
    shifted = cv2.remap(
        right, (u_right + 3).astype(np.float32), rows.astype(np.float32), cv2.INTER_LINEAR
    )
    assert np.abs(shifted - rendered.left.astype(np.float32)[rows, cols]).mean() > 5.0


def test_load_deforms_depth_around_the_contact(tissue):
    rig = default_rig(320, 180)
    kw = dict(noise_sigma=0.0, rng=np.random.default_rng(0))
    rest = render_scene(rig, tissue.with_load(None), smooth_pattern(), **kw)
    pulled = render_scene(rig, tissue, smooth_pattern(), **kw)
    change = rest.depth_left_m - pulled.depth_left_m  # pulled towards the camera
    assert 0.004 < change.max() < 0.0065
    row, col = np.unravel_index(np.argmax(change), change.shape)
    contact = rig.left.project(np.array([[0.009, 0.004, 0.06]]))[0]  # near contact + lateral pull
    assert abs(col - contact[0]) < 60 and abs(row - contact[1]) < 60
    assert not np.array_equal(rest.left, pulled.left)


def test_plane_with_shading_and_tint():
    rig = default_rig(320, 180)
    plane = Plane(np.eye(3), np.array([0.0, 0.0, 0.05]), texture=UniformAlbedo((0.5, 0.5, 1.0)))
    white = np.full((768, 1024, 3), 255, np.uint8)
    out = render_scene(rig, plane, white, noise_sigma=0.0, rng=np.random.default_rng(0))
    assert np.allclose(out.depth_left_m[out.valid_left], 0.05, atol=1e-7)
    centre = out.left[80:100, 150:170].astype(np.float32).mean(axis=(0, 1))
    assert centre[2] > 200 and abs(centre[0] / centre[2] - 0.5) < 0.02  # tint ratio kept


def test_a_size_rendered_on_every_pixel_keeps_its_size_and_truth(tissue):
    # 160x90: no coarse grid divides it, so every pixel is ray-cast; its depth must agree
    # with the 320x180 render (strided, upsampled) averaged over the matching 2x2 blocks
    small = render_scene(
        default_rig(160, 90),
        tissue,
        smooth_pattern(),
        noise_sigma=0.0,
        pattern_blur=0.0,
        rng=np.random.default_rng(0),
    )
    for image in (small.left, small.right):
        assert image.shape == (90, 160, 3)
    assert small.depth_left_m.shape == small.valid_left.shape == (90, 160)
    large = render_scene(
        default_rig(320, 180),
        tissue,
        smooth_pattern(),
        noise_sigma=0.0,
        pattern_blur=0.0,
        rng=np.random.default_rng(0),
    )
    blocks = large.depth_left_m.reshape(90, 2, 160, 2).mean(axis=(1, 3))
    both = small.valid_left & large.valid_left.reshape(90, 2, 160, 2).all(axis=(1, 3))
    assert both.mean() > 0.9
    assert np.median(np.abs(small.depth_left_m[both] - blocks[both])) < 1e-4
