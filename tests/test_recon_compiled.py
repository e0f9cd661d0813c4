"""The compiled decoder and verification give exactly the numpy formulation's results on
rendered frames (tests/recon_numpy_reference.py), including the repair of wrong matches."""

import numpy as np
import pytest

from tests import recon_numpy_reference as reference
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.recon import Reconstructor, make_pattern
from vbfe.recon.kernels import CORRECTED, KEPT, REJECTED
from vbfe.recon.matching import sgbm_disparity
from vbfe.recon.verify import verify_disparity
from vbfe.truth import calibration_from_rig


@pytest.fixture(scope="module")
def decoded():
    rig = default_rig(640, 360, working_distance_m=0.06)
    rng = np.random.default_rng(11)
    pair = render_scene(rig, TissueSurface(distance_m=0.06, texture=tissue_texture(rng)),
                        make_pattern(rig.projector.width, rig.projector.height), rng=rng)
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
    assert np.array_equal(decoder.decode(half_flat, period_px=left.period_px).index,
                          reference.decode_index(decoder, half_flat, left.period_px))


def test_compiled_verification_gives_the_numpy_disparities(decoded):
    reconstructor, _, left, right, disparity = decoded
    search = reconstructor.params.verify_search_px
    everywhere = np.ones(disparity.shape, bool)  # the numpy version verified every pixel
    wrong = disparity.copy()
    wrong[100:160, 200:320] += 2 * left.period_px  # two fringes off: repaired or rejected
    wrong[200:240, 100:140] += 1.0  # one pixel off: within the search
    for candidate in (disparity, wrong):
        out, status, counts = verify_disparity(candidate, left, right, search, everywhere)
        assert np.array_equal(out, reference.verify(candidate, left, right, search),
                              equal_nan=True)
        assert counts["kept"] == np.count_nonzero(status == KEPT)
        assert counts["corrected"] == np.count_nonzero(status == CORRECTED)
        assert counts["rejected"] == np.count_nonzero(status == REJECTED)
    assert counts["corrected"] > 1000 and counts["rejected"] > counts["corrected"] // 10
