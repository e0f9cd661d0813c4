"""Frame reconstruction on a rendered tissue pair from the simulated bench, against its truth."""

import numpy as np
import pytest

from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.recon import FrameCloud, ReconError, Reconstructor, SgbmParams, make_pattern
from vbfe.recon.decode import FringeDecoder
from vbfe.recon.kernels import KEPT, triangulate
from vbfe.recon.matching import sgbm_disparity
from vbfe.recon.verify import verify_disparity
from vbfe.truth import calibration_from_rig, evaluate_against_truth, rectified_truth

WORKING_DISTANCE_M = 0.06


@pytest.fixture(scope="module")
def scene():
    rig = default_rig(640, 360, working_distance_m=WORKING_DISTANCE_M)
    rng = np.random.default_rng(3)
    surface = TissueSurface(distance_m=WORKING_DISTANCE_M, texture=tissue_texture(rng))
    pattern = make_pattern(rig.projector.width, rig.projector.height)
    return rig, calibration_from_rig(rig), render_scene(rig, surface, pattern, rng=rng)


def _truth_fringe(pair, projector_width: int) -> np.ndarray:
    u = pair.proj_uv_left[..., 0]
    inside = (u >= -0.5) & (u < projector_width - 0.5) & pair.valid_left
    return np.where(inside, np.floor((u + 0.5) * 64 / projector_width), -1).astype(int)


def test_decoded_fringe_indices_match_the_projector_columns_seen(scene):
    rig, _, pair = scene
    truth = _truth_fringe(pair, rig.projector.width)
    decoded = FringeDecoder().decode(pair.left).index
    lit = truth >= 0
    readable = decoded >= 0
    assert readable[lit].mean() > 0.8
    assert readable[~lit].mean() < 0.05
    close = np.abs(decoded - truth) <= 1  # pixels on a fringe boundary may go either way
    assert close[readable & lit].mean() > 0.99


def test_verification_lowers_bad_pixels_and_depth_error_is_below_one_percent(scene):
    _, calibration, pair = scene
    truth = (pair.disparity_left_px, pair.depth_left_m, pair.valid_left)
    bare = evaluate_against_truth(
        Reconstructor(calibration, SgbmParams(), verify=False).process(pair.left, pair.right),
        *truth,
    )
    cloud = Reconstructor(calibration, SgbmParams(), verify=True).process(pair.left, pair.right)
    verified = evaluate_against_truth(cloud, *truth)
    assert verified.bad_pixel_rate < bare.bad_pixel_rate
    assert verified.median_abs_depth_error_m <= 0.01 * WORKING_DISTANCE_M
    assert verified.p95_abs_depth_error_m < bare.p95_abs_depth_error_m
    assert verified.valid_fraction > 0.3  # the pattern covers about half of the view
    assert len(cloud.points) == verified.n_valid == int(cloud.valid.sum())
    assert cloud.colors.shape == cloud.points.shape and cloud.colors.dtype == np.uint8


def test_distorted_rig_is_rectified_before_matching():
    rig = default_rig(640, 360, working_distance_m=WORKING_DISTANCE_M, distortion=True)
    rng = np.random.default_rng(4)
    surface = TissueSurface(distance_m=WORKING_DISTANCE_M, texture=tissue_texture(rng))
    pair = render_scene(
        rig, surface, make_pattern(rig.projector.width, rig.projector.height), rng=rng
    )
    calibration = calibration_from_rig(rig)
    truth = rectified_truth(calibration, pair.depth_left_m, pair.valid_left)
    report = evaluate_against_truth(
        Reconstructor(calibration, SgbmParams()).process(pair.left, pair.right), *truth
    )
    assert report.valid_fraction > 0.3
    assert report.median_abs_depth_error_m <= 0.01 * WORKING_DISTANCE_M
    assert report.bad_pixel_rate < 0.001


def test_injected_whole_fringe_errors_are_corrected_or_rejected(scene):
    _, calibration, pair = scene
    params = Reconstructor(calibration).params  # the range derived from the geometry
    decoder = FringeDecoder()
    left, right = decoder.decode(pair.left), decoder.decode(pair.right)
    disparity = sgbm_disparity(pair.left, pair.right, params)
    kept, _, _ = verify_disparity(disparity, left, right, params.verify_search_px)
    wrong = disparity.copy()
    block = (slice(150, 200), slice(300, 400))
    wrong[block] += 2 * left.period_px  # two fringes off: a different code
    checked, status, counts = verify_disparity(wrong, left, right, params.verify_search_px)
    valid = np.isfinite(checked)
    error = np.abs(checked[block] - pair.disparity_left_px[block])
    assert np.all(error[valid[block]] <= 1.5)
    assert counts["rejected"] > 0
    assert valid[block].sum() < np.isfinite(kept[block]).sum()


def test_triangulation_follows_z_equals_f_b_over_d_minus_doffs_and_y_its_own_focal_length():
    disparity = np.full((3, 4), 20.0, np.float32)
    disparity[0, 0] = np.nan
    disparity[2, 3] = 1.5  # at or beyond infinity with doffs = 2: no point
    status = np.full((3, 4), KEPT, np.uint8)
    image = np.arange(36, dtype=np.uint8).reshape(3, 4, 3)
    points, colours, verified = triangulate(
        disparity, status, image, 500.0, 0.004, 1.5, 1.0, 2.0, 400.0
    )
    assert points.shape == (10, 3) and verified.all()
    np.testing.assert_allclose(points[:, 2], 500 * 0.004 / 18, rtol=1e-6)
    z = 500 * 0.004 / 18
    np.testing.assert_allclose(points[0], [(1 - 1.5) * z / 500, (0 - 1.0) * z / 400, z], rtol=1e-6)
    assert np.array_equal(colours[0], image[0, 1, ::-1])  # BGR image, RGB colours
    assert np.isnan(disparity[2, 3]) and status[2, 3] == 0


def test_frame_cloud_points_agree_with_the_rendered_depth(scene):
    _, calibration, pair = scene
    cloud = Reconstructor(calibration, SgbmParams()).process(pair.left, pair.right)
    assert isinstance(cloud, FrameCloud)
    rows, cols = np.nonzero(cloud.valid)
    truth_z = pair.depth_left_m[rows, cols]
    assert np.median(np.abs(cloud.points[:, 2] - truth_z)) < 0.0006
    expected_x = (cols - calibration.cx) * cloud.points[:, 2] / calibration.f
    np.testing.assert_allclose(cloud.points[:, 0], expected_x, rtol=1e-4, atol=1e-7)


def test_images_of_another_size_are_a_clear_error(scene):
    _, calibration, pair = scene
    reconstructor = Reconstructor(calibration, SgbmParams())
    with pytest.raises(ReconError, match="320x180.*640x360"):
        reconstructor.process(pair.left[::2, ::2], pair.right[::2, ::2])


def test_sgbm_settings_come_from_the_rig_table():
    from vbfe.common.errors import ConfigError
    from vbfe.rig_config import builtin_rig

    params = builtin_rig().sgbm
    assert params.num_disparities % 16 == 0 and params.block_size % 2 == 1
    with pytest.raises(ReconError, match="num_disparities"):
        SgbmParams.from_config({"num_disparities": 100})
    with pytest.raises(ConfigError, match=r"unknown key 'blocksize' in \[sgbm\]"):
        SgbmParams.from_config({"blocksize": 5})


def test_a_search_narrowed_to_the_scenes_depths_keeps_its_cloud(scene):
    """``search_depths`` around the depths a cloud spans (vbfe live: its rest frame's ± a
    margin) matches fewer disparities with the same extent and accuracy; a search that cuts
    the surface off shows in the edge share."""
    _, calibration, pair = scene
    truth = (pair.disparity_left_px, pair.depth_left_m, pair.valid_left)
    whole = Reconstructor(calibration, SgbmParams()).process(pair.left, pair.right)
    near, far = np.percentile(whole.points[:, 2], [0.5, 99.5]) * 1e3  # 58-77 mm
    narrow = Reconstructor(calibration, SgbmParams())
    searched = narrow.search_depths(near - 10, far + 10)
    assert searched.num_disparities == narrow.params.num_disparities // 2
    cloud = narrow.process(pair.left, pair.right)
    columns = [np.flatnonzero(c.valid.any(axis=0))[[0, -1]] for c in (whole, cloud)]
    assert np.array_equal(*columns)
    before, after = (evaluate_against_truth(c, *truth) for c in (whole, cloud))
    assert abs(after.n_valid - before.n_valid) < 0.002 * before.n_valid
    assert after.median_abs_depth_error_m < 1.02 * before.median_abs_depth_error_m
    assert after.p95_abs_depth_error_m < 1.02 * before.p95_abs_depth_error_m
    assert after.bad_pixel_rate <= before.bad_pixel_rate + 1e-4
    assert cloud.edge_fraction < 1e-3
    # depths the rig's range does not narrow leave the search as it was
    assert narrow.search_depths(1.0, 1000.0) == narrow.params
    narrow.search_depths(near + 2, far - 8)
    assert narrow.process(pair.left, pair.right).edge_fraction > 0.1
