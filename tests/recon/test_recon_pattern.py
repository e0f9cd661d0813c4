"""The projector pattern: De Bruijn-coded hue, full saturation, cosine value per fringe."""

import cv2
import numpy as np
import pytest

from vbfe.common.errors import DeviceError
from vbfe.drivers.projector.pattern import SYMBOL_CHANNEL_BGR, de_bruijn, fringe_symbols
from vbfe.recon import make_pattern, save_pattern
from vbfe.recon.debruijn import code_lookup, window_codes


def test_de_bruijn_3_4_has_every_window_of_four_exactly_once():
    sequence = de_bruijn(3, 4)
    assert len(sequence) == 81
    cyclic = np.concatenate([sequence, sequence[:3]])
    codes = window_codes(cyclic, 3, 4)
    assert sorted(codes.tolist()) == list(range(81))


def test_code_lookup_finds_the_position_of_each_window_and_rejects_repeats():
    symbols = fringe_symbols(64)
    table = code_lookup(symbols)
    codes = window_codes(symbols)
    assert np.array_equal(table[codes], np.arange(61))
    assert (table >= 0).sum() == 61
    with pytest.raises(ValueError):
        code_lookup(np.array([0, 0, 0, 0, 0]))


@pytest.mark.parametrize("width,height", [(1024, 768), (1280, 720), (300, 7)])
def test_pattern_colours_follow_the_code_and_value_peaks_at_fringe_centres(width, height):
    pattern = make_pattern(width, height)
    assert pattern.shape == (height, width, 3) and pattern.dtype == np.uint8
    assert np.array_equal(pattern[0], pattern[-1])  # vertical stripes
    symbols = fringe_symbols(64)
    edges = np.linspace(0, width, 65)
    hsv = cv2.cvtColor(pattern[:1], cv2.COLOR_BGR2HSV_FULL)[0]
    for k in range(64):
        centre = int((edges[k] + edges[k + 1]) / 2)
        assert np.argmax(pattern[0, centre]) == SYMBOL_CHANNEL_BGR[symbols[k]]
        assert pattern[0, centre].max() >= 200  # V ~ 1 in the middle (sampled)
        assert hsv[centre, 1] >= 250  # S = 1
    inner_edges = np.rint(edges[1:-1] - 0.5).astype(int)  # pixel whose centre is nearest
    assert pattern[0, inner_edges].max(axis=1).max() <= 60  # dark between fringes


def test_save_pattern_writes_a_png_with_the_same_pixels(tmp_path):
    path = save_pattern(tmp_path / "pattern.png", 640, 480)
    assert np.array_equal(cv2.imread(str(path)), make_pattern(640, 480))
    with pytest.raises(DeviceError, match="too small"):
        make_pattern(100, 10)
    with pytest.raises(DeviceError, match="could not write"):
        save_pattern(tmp_path / "missing" / "pattern.png", 640, 480)
