"""The compiled decoder (colour normalisation included), verification, fixed-point conversion
and edge share give exactly the numpy/OpenCV formulation's results on rendered frames
(tests/recon_numpy_reference.py), including the repair of wrong matches."""

from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np
import pytest

from tests import recon_numpy_reference as reference
from vbfe.calib.calibration import Calibration
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.recon import ColorModel, Reconstructor, kernels, make_pattern
from vbfe.recon.color import remove_base_color
from vbfe.recon.decode import FringeDecoder
from vbfe.recon.kernels import CORRECTED, KEPT, REJECTED
from vbfe.recon.matching import disparity_px, sgbm_disparity
from vbfe.recon.quality import decoded_fraction
from vbfe.recon.verify import coded_region, verify_disparity
from vbfe.truth import calibration_from_rig


@pytest.fixture(scope="module")
def decoded():
    rig = default_rig(640, 360, working_distance_m=0.06)
    rng = np.random.default_rng(11)
    pair = render_scene(
        rig,
        TissueSurface(distance_m=0.06, texture=tissue_texture(rng)),
        make_pattern(rig.projector.width, rig.projector.height),
        rng=rng,
    )
    reconstructor = Reconstructor(calibration_from_rig(rig))
    left = reconstructor.decoder.decode(pair.left)
    right = reconstructor.decoder.decode(pair.right, period_px=left.period_px)
    disparity = sgbm_disparity(pair.left, pair.right, reconstructor.params)
    return reconstructor, pair, left, right, disparity


def test_compiled_decoder_gives_the_numpy_fringe_indices(decoded):
    reconstructor, pair, left, right, _ = decoded
    decoder = reconstructor.decoder
    for image, code in ((pair.left, left), (pair.right, right)):
        expected = reference.decode_index(decoder, image, left.period_px)
        assert (expected >= 0).mean() > 0.5
        assert np.array_equal(code.index, expected)
    half_flat = pair.left.copy()
    half_flat[:, 320:] = 90  # runs far longer than numpy's 128-element pairwise blocks
    assert np.array_equal(
        decoder.decode(half_flat, period_px=left.period_px).index,
        reference.decode_index(decoder, half_flat, left.period_px),
    )
    shorter = pair.left[:357]  # the last block of row_step rows is shorter
    assert decoder.row_step == 5
    shorter_index = decoder.decode(shorter, period_px=left.period_px).index
    assert np.array_equal(shorter_index, reference.decode_index(decoder, shorter, left.period_px))
    for index in (left.index, right.index, shorter_index):  # counted on one row per block
        expected_share = np.count_nonzero(index >= 0) / index.size
        assert decoded_fraction(index, decoder.row_step) == expected_share


def test_compiled_verification_gives_the_numpy_disparities(decoded):
    reconstructor, _, left, right, disparity = decoded
    search = reconstructor.params.verify_search_px
    everywhere = np.ones(disparity.shape, bool)  # the numpy version verified every pixel
    wrong = disparity.copy()
    wrong[100:160, 200:320] += 2 * left.period_px  # two fringes off: repaired or rejected
    wrong[200:240, 100:140] += 1.0  # one pixel off: within the search
    for candidate in (disparity, wrong):
        out, status, counts = verify_disparity(candidate, left, right, search, everywhere)
        assert np.array_equal(out, reference.verify(candidate, left, right, search), equal_nan=True)
        assert counts["kept"] == np.count_nonzero(status == KEPT)
        assert counts["corrected"] == np.count_nonzero(status == CORRECTED)
        assert counts["rejected"] == np.count_nonzero(status == REJECTED)
    assert counts["corrected"] > 1000 and counts["rejected"] > counts["corrected"] // 10


def test_coded_region_on_its_cell_grid_and_verification_split_over_two_threads(decoded):
    reconstructor, _, left, right, disparity = decoded
    search = reconstructor.params.verify_search_px
    index = left.index.copy()
    index[:, :250] = -1  # half the image unreadable: the region has an edge
    for period in (left.period_px, 5.3, 13.0):  # cells dividing the image and not
        code = replace(left, index=index, period_px=period)
        full = reference.coded_region(index, period)
        assert 0.2 < full.mean() < 0.9
        assert np.array_equal(coded_region(code), full)
        by_grid = verify_disparity(disparity, code, right, search)
        by_map = verify_disparity(disparity, code, right, search, full)
        assert np.array_equal(by_grid[0], by_map[0], equal_nan=True)
        assert np.array_equal(by_grid[1], by_map[1]) and by_grid[2] == by_map[2]
        with ThreadPoolExecutor(1) as pool:
            split = verify_disparity(disparity, code, right, search, pool=pool)
        assert np.array_equal(split[0], by_map[0], equal_nan=True)
        assert np.array_equal(split[1], by_map[1]) and split[2] == by_map[2]


def test_compiled_colour_normalisation_gives_opencvs_values(decoded):
    _, pair, _, _, _ = decoded
    rng = np.random.default_rng(5)
    images = [
        np.ascontiguousarray(pair.left[::3]),
        np.ascontiguousarray(pair.right[::3]),
        rng.integers(0, 256, (37, 101, 3), np.uint8),  # odd sizes, percentile ranks
        rng.integers(0, 256, (1, 7, 3), np.uint8),
        rng.integers(0, 256, (2, 5, 3), np.uint8),
    ]
    for image in images:
        for window in (3, 10, 31, 32, 224):  # windows wider than the image reflect again
            assert np.array_equal(
                remove_base_color(image, window), reference.remove_base_color(image, window)
            ), (image.shape, window)


def test_compiled_decoder_with_crosstalk_gives_the_opencv_fringe_indices(decoded):
    _, pair, left, _, _ = decoded
    mixing = np.array([[0.8, 0.15, 0.05], [0.1, 0.8, 0.1], [0.05, 0.15, 0.8]])
    decoder = FringeDecoder(ColorModel(mixing, np.array([4.0, 2.0, 3.0])))
    expected = reference.decode_index(decoder, pair.left, left.period_px)
    assert (expected >= 0).mean() > 0.3
    assert np.array_equal(decoder.decode(pair.left, period_px=left.period_px).index, expected)


def test_compiled_fixed_point_conversion_and_edge_share(decoded):
    reconstructor, pair, _, _, disparity = decoded
    params = reconstructor.params
    raw = params.create(3).compute(pair.left, pair.right)
    assert np.array_equal(
        disparity, reference.disparity_px(raw, params.min_disparity), equal_nan=True
    )
    low = params.min_disparity
    shares = []
    for high in (low + params.num_disparities - 1, int(np.nanmedian(disparity))):  # half at an end
        converted, share = disparity_px(raw, replace(params, num_disparities=high - low + 1))
        assert np.array_equal(converted, disparity, equal_nan=True)
        assert share == reference.edge_fraction(disparity, low, high)
        shares.append(share)
    assert shares[1] > 0.3


def test_reconstruction_split_over_two_threads_gives_the_same_cloud(decoded):
    reconstructor, pair, _, _, _ = decoded
    alone = Reconstructor(reconstructor.calibration, parallel_decode=False)
    together = Reconstructor(reconstructor.calibration, parallel_decode=True)
    one, two = alone.process(pair.left, pair.right), together.process(pair.left, pair.right)
    assert len(one.points) > 100_000
    assert np.array_equal(one.disparity, two.disparity, equal_nan=True)
    for name in ("points", "colors", "verified", "status"):
        assert np.array_equal(getattr(one, name), getattr(two, name)), name
    assert one.counts == two.counts and one.decoded_fraction == two.decoded_fraction


def test_verification_drops_matches_beyond_infinity_as_triangulation_did(decoded):
    reconstructor, pair, _, _, sgbm = decoded
    cal = reconstructor.calibration
    doffs = -float(np.round(np.nanmedian(sgbm)))  # about half the matches at or beyond infinity
    shifted = Calibration.rectified(cal.f, cal.fy, cal.B, cal.cx, cal.cy, cal.image_size, doffs)
    for parallel in (False, True):
        fused = Reconstructor(shifted, reconstructor.params, parallel_decode=parallel)
        cloud = fused.process(pair.left, pair.right)
        left = fused.decoder.decode(pair.left)
        right = fused.decoder.decode(pair.right, period_px=left.period_px)
        disparity = sgbm_disparity(pair.left, pair.right, fused.params)
        out, status, counts = verify_disparity(
            disparity, left, right, fused.params.verify_search_px
        )
        beyond = np.count_nonzero(out <= -doffs)
        assert beyond > 10_000 and np.count_nonzero(out > -doffs) > 10_000
        points, colors, verified = kernels.triangulate(
            out, status, pair.left, cal.f, cal.B, cal.cx, cal.cy, -doffs, cal.fy
        )
        assert cloud.counts == counts
        assert np.array_equal(cloud.disparity, out, equal_nan=True)
        assert np.array_equal(cloud.status, status)
        for name, expected in (("points", points), ("colors", colors), ("verified", verified)):
            assert np.array_equal(getattr(cloud, name), expected), name
