"""Projector calibration from Gray code on the board, captured on the simulated bench through the
camera and projector drivers (``calibrate projector-capture``'s code)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vbfe.calib.board import BoardSpec
from vbfe.calib.calibration import Calibration
from vbfe.calib.commands import projector_capture
from vbfe.calib.projector import (
    GrayCodeCapture,
    calibrate_projector,
    load_captures,
    save_captures,
    with_projector,
)
from vbfe.common.errors import CalibrationError
from vbfe.rig_config import builtin_rig
from vbfe.truth import board_config, calibration_from_rig, true_rig

SPEC = BoardSpec()
CONFIG = board_config(builtin_rig(), on_a_stand=True, fps=10.0, seed=0)
RIG = true_rig(CONFIG)
N_POSES = 8


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> list[GrayCodeCapture]:
    """Captures of the board at N_POSES poses, through the bench's camera and projector."""
    folder = tmp_path_factory.mktemp("gray")
    written = projector_capture(CONFIG, folder, N_POSES)
    assert [p.name for p in written] == [f"pose_{i:03d}" for i in range(N_POSES)]
    return load_captures(folder)


def test_projector_intrinsics_and_pose_match_the_bench(tmp_path, captures):
    camera = calibration_from_rig(RIG).replace(
        K_proj=None, D_proj=None, R_proj=None, T_proj=None, projector_size=None
    )
    size = (RIG.projector.width, RIG.projector.height)
    result = calibrate_projector(list(captures), SPEC, camera, size)
    K, K_true = result.K, RIG.projector.K
    for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)):
        assert abs(K[i, j] / K_true[i, j] - 1) < 0.02, (i, j, K[i, j], K_true[i, j])
    assert result.rms_px < 1.0
    assert np.linalg.norm(result.T - RIG.T_proj) < 0.05 * np.linalg.norm(RIG.T_proj)
    angle = np.degrees(np.linalg.norm(cv2.Rodrigues(result.R @ RIG.R_proj.T)[0]))
    assert angle < 1.0
    # stored in the calibration file next to the stereo parameters
    path = with_projector(camera, result, size).save(tmp_path / "cal.yaml")
    back = Calibration.load(path)
    assert np.allclose(back.K_proj, result.K) and back.projector_size == size
    assert np.allclose(back.P1, camera.P1)


def test_captures_round_trip_through_a_folder(tmp_path, captures):
    save_captures(tmp_path, list(captures[:1]))
    (back,) = load_captures(tmp_path)
    assert len(back.patterns) == len(captures[0].patterns) == 40
    assert np.array_equal(back.white, captures[0].white)


def test_board_outside_the_projected_area_is_a_clear_error(captures):
    camera = calibration_from_rig(RIG)
    dark = [GrayCodeCapture(c.black, c.black, c.patterns) for c in captures[:4]]
    with pytest.raises(CalibrationError, match="only 0 of 4 poses.*lit by the projector"):
        calibrate_projector(dark, SPEC, camera, (1024, 768))
    with pytest.raises(CalibrationError, match="needs 40 Gray-code images per pose, got 39"):
        calibrate_projector(
            [GrayCodeCapture(c.white, c.black, c.patterns[:39]) for c in captures[:4]],
            SPEC,
            camera,
            (1024, 768),
        )
