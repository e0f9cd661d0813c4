"""The simulated endoscope's optics (drivers/sim/optics.py) through the bench's configuration:
a dim, soft, compressed camera darkens and widens the board's edges as configured."""

from __future__ import annotations

import numpy as np
import pytest

from vbfe.calib.board import BoardDetector, BoardSpec
from vbfe.calib.edge_width import edge_width_px
from vbfe.common.errors import ConfigError, DeviceError
from vbfe.drivers.sim import SimBench

SPEC = BoardSpec(squares_x=10, squares_y=7, square_m=0.003, target="chessboard")
POSE = [[0.1, -0.15, 0.05, -0.015, -0.01, 0.05]]  # the board facing the endoscope at 50 mm


def left_frame(**bench: object) -> np.ndarray:
    sim = SimBench(
        scene="board",
        board="chessboard",
        board_squares_x=10,
        board_squares_y=7,
        board_poses=POSE,
        **bench,
    )
    with sim.camera() as camera:
        return camera.read(timeout_s=1.0).left[..., 0]


def test_board_optics_darken_and_blur_the_board_as_configured():
    clean = left_frame()
    dim = left_frame(board_optics={"exposure": 0.2, "defocus_px": 2.5, "jpeg_quality": 70})
    assert dim.mean() == pytest.approx(0.2 * clean.mean(), rel=0.05)
    detector = BoardDetector(SPEC)
    found = detector.detect(clean)
    assert len(found) == 54 and len(detector.detect(dim)) == 54
    sharp = edge_width_px(clean, found.ids, found.corners, 9)
    soft = edge_width_px(dim, found.ids, found.corners, 9)
    # the clean camera's σ 0.5 px blur plus a 2.5 px defocus: widths add in quadrature
    assert soft == pytest.approx(np.hypot(sharp, 2.563 * 2.5), rel=0.15)
    vignetted = left_frame(board_optics={"vignetting": 0.5})
    corner, centre = vignetted[:20, :20].mean(), vignetted[170:190, 310:330].mean()
    assert corner < 0.6 * left_frame()[:20, :20].mean() and centre > 100


def test_bad_optics_settings_are_refused_by_name():
    with pytest.raises(DeviceError, match="exposure = 0"):
        left_frame(board_optics={"exposure": 0.0})
    with pytest.raises(ConfigError, match="unknown key 'focus'"):
        left_frame(board_optics={"focus": 1.0})
