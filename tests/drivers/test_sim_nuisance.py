"""The bench's tissue/optics nuisance knobs: off by default, each doing what it models."""

import numpy as np
import pytest

from vbfe.common.errors import DeviceError
from vbfe.drivers.sim import SimBench
from vbfe.drivers.sim.nuisance import Nuisance
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import Plane, TissueSurface, UniformAlbedo
from vbfe.recon import make_pattern

RIG = default_rig(320, 180)
WHITE_PLANE = Plane(np.eye(3), np.array([0.0, 0.0, 0.06]), texture=UniformAlbedo((1, 1, 1)))


def _flat(bgr):
    return np.full((RIG.projector.height, RIG.projector.width, 3), bgr, np.uint8)


def _render(surface, pattern, **nuisance):
    return render_scene(
        RIG,
        surface,
        pattern,
        rng=np.random.default_rng(0),
        noise_sigma=0.0,
        ambient=0.0,
        nuisance=Nuisance(**nuisance),
    )


def test_default_nuisance_changes_nothing():
    pattern = make_pattern(RIG.projector.width, RIG.projector.height)
    plain = render_scene(RIG, TissueSurface(), pattern, rng=np.random.default_rng(3))
    with_default = render_scene(
        RIG, TissueSurface(), pattern, rng=np.random.default_rng(3), nuisance=Nuisance()
    )
    np.testing.assert_array_equal(plain.left, with_default.left)
    np.testing.assert_array_equal(plain.right, with_default.right)


def test_crosstalk_leaks_each_primary_into_the_other_channels():
    red = _render(WHITE_PLANE, _flat((0, 0, 255)), crosstalk=0.3).left[60:120, 100:220]
    b, g, r = (float(red[..., k].mean()) for k in range(3))
    assert r > 100
    assert b / (r / 0.7) == pytest.approx(0.15, abs=0.02)
    assert g / (r / 0.7) == pytest.approx(0.15, abs=0.02)


def test_gamma_vignetting_and_blur_act_as_modelled():
    grey = _flat((128, 128, 128))
    linear = _render(WHITE_PLANE, grey).left.astype(float)
    gamma = _render(WHITE_PLANE, grey, projector_gamma=2.2).left.astype(float)
    centre = (slice(80, 100), slice(150, 170))
    assert gamma[centre].mean() / linear[centre].mean() == pytest.approx(
        (128 / 255) ** 1.2, rel=0.05
    )
    vignetted = _render(WHITE_PLANE, grey, vignetting=0.5).left.astype(float)
    v, u = np.mgrid[0:180, 0:320]
    expected = 1 - 0.5 * ((u - 159.5) ** 2 + (v - 89.5) ** 2) / (160**2 + 90**2)
    lit = linear[..., 1] > 40
    assert expected[lit].min() < 0.8  # the lit area reaches well off-centre
    ratio = vignetted[..., 1][lit] / linear[..., 1][lit]
    assert np.median(np.abs(ratio - expected[lit])) < 0.02
    pattern = make_pattern(RIG.projector.width, RIG.projector.height)
    sharp = _render(WHITE_PLANE, pattern).left.astype(float)
    for blurred in (
        _render(WHITE_PLANE, pattern, subsurface_blur_mm=0.3).left,
        _render(WHITE_PLANE, pattern, motion_blur_px=6.0).left,
    ):
        contrast = np.abs(np.diff(blurred.astype(float), axis=1))[60:120].mean()
        assert contrast < 0.6 * np.abs(np.diff(sharp, axis=1))[60:120].mean()


def test_speculars_saturate_and_differ_between_the_eyes():
    pair = render_scene(
        RIG,
        TissueSurface(),
        _flat((200, 200, 200)),
        rng=np.random.default_rng(0),
        nuisance=Nuisance(specular=10.0),
    )
    saturated = [image.min(axis=2) == 255 for image in (pair.left, pair.right)]
    assert 0.001 < saturated[0].mean() < 0.2
    assert np.mean(saturated[0] != saturated[1]) > 0.2 * saturated[0].mean()


def test_bench_table_keys_reach_the_renderer_and_bad_values_are_refused():
    bench = SimBench(
        width=320,
        height=180,
        crosstalk=0.2,
        specular=3.0,
        motion_blur_exposure_ms=20.0,
        pull_speed_m_per_s=0.01,
        albedo_bgr=[0.3, 0.35, 0.9],
    )
    nuisance = bench.renderer.nuisance
    assert nuisance.crosstalk == 0.2 and nuisance.specular == 3.0
    # 0.2 mm of travel at the 60 mm working distance, seen with f ≈ 228 px
    assert nuisance.motion_blur_px == pytest.approx(0.0002 * RIG.left.f / 0.06, rel=1e-6)
    assert SimBench.from_description(bench.describe()).renderer.nuisance == nuisance
    with pytest.raises(DeviceError, match=r"\[bench\].*crosstalk"):
        SimBench.from_config({"crosstalk": 0.9})
