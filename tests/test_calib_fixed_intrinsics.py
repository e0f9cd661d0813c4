"""Fixed intrinsics on a digitiser's principal-point offset (issue 56): OpenCV's stereo sample
with the right eye shifted 85 px in x (each image padded on one side, as a digitiser that samples
the two channels' lines from different starts crops them), each eye's intrinsics from
`calibrate camera` on a weaker set of views (the first 9), then `calibrate stereo --intrinsics`
against the joint solve of all 13 pairs, through the real CLI."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.calib_image_sets import VIEWS, sharp
from tests.cli import vbfe
from vbfe.calib.calibration import load_calibration
from vbfe.calib.rectify import rectified_fractions

pytestmark = pytest.mark.slow  # four calibrations of the sample in subprocesses
SHIFT_PX = 85
BOARD = ("--target", "chessboard", "--inner-corners", "9x6", "--square-mm", "25")
WEAK = 9  # views of each eye's own calibration


@pytest.fixture(scope="module")
def shifted(tmp_path_factory) -> Path:
    """The sample in left/leftNN.png + right/rightNN.png, the right eye 85 px to the right."""
    folder = tmp_path_factory.mktemp("shifted")
    for eye in ("left", "right"):
        (folder / eye).mkdir()
    for view, (left, right) in zip(VIEWS, sharp(), strict=True):
        pad = {"value": 128, "borderType": cv2.BORDER_CONSTANT}
        cv2.imwrite(
            str(folder / "left" / f"left{view}.png"),
            cv2.copyMakeBorder(left, 0, 0, 0, SHIFT_PX, **pad),
        )
        cv2.imwrite(
            str(folder / "right" / f"right{view}.png"),
            cv2.copyMakeBorder(right, 0, 0, SHIFT_PX, 0, **pad),
        )
    return folder


@pytest.fixture(scope="module")
def solved(shifted, tmp_path_factory) -> dict[str, Path]:
    """The joint solve, each eye's camera file (weaker views) and the fixed-intrinsics solve."""
    out = tmp_path_factory.mktemp("solved")
    files = {"joint": out / "joint.yaml", "fixed": out / "fixed.yaml"}
    run = vbfe("calibrate", "stereo", shifted, *BOARD, "--no-report", "-o", files["joint"])
    assert run.returncode == 0, run.stderr
    for eye in ("left", "right"):
        files[eye] = out / f"{eye}.yaml"
        weak = shifted / eye / f"{eye}0*.png"  # views 01-09
        run = vbfe("calibrate", "camera", weak, *BOARD, "-o", files[eye])
        assert run.returncode == 0, run.stderr
    run = vbfe(
        "calibrate", "stereo", shifted, *BOARD, "--no-report", "-o", files["fixed"],
        "--intrinsics", files["left"], files["right"],
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    return files


def _kept(cal) -> float:
    return min(
        min(rectified_fractions(K, D, R, P, cal.image_size))
        for K, D, R, P in ((cal.K1, cal.D1, cal.R1, cal.P1), (cal.K2, cal.D2, cal.R2, cal.P2))
    )


def test_fixed_intrinsics_agree_with_the_joint_solve(solved):
    joint, fixed = load_calibration(solved["joint"]), load_calibration(solved["fixed"])
    assert fixed.K2[0, 2] - fixed.K1[0, 2] == pytest.approx(joint.K2[0, 2] - joint.K1[0, 2], abs=2)
    assert joint.K2[0, 2] - joint.K1[0, 2] > SHIFT_PX - 25  # the sample's own offset is -15 px
    for K_fixed, K_joint in ((fixed.K1, joint.K1), (fixed.K2, joint.K2)):
        assert np.diag(K_fixed)[:2] / np.diag(K_joint)[:2] == pytest.approx([1, 1], abs=2e-3)
    assert fixed.B / joint.B == pytest.approx(1, abs=2e-3)
    assert fixed.rms_stereo_px / joint.rms_stereo_px == pytest.approx(1, abs=0.1)
    assert _kept(fixed) >= 0.5 and _kept(joint) >= 0.5  # the gate's default limit
    assert {row[3] for row in fixed.info["gates"]} == {"pass", "not checked"}


def test_a_refused_fixed_solve_offers_the_joint_numbers_side_by_side(shifted, solved, tmp_path):
    out = tmp_path / "x.yaml"
    run = vbfe(
        "calibrate", "stereo", shifted, *BOARD, "--no-report", "-o", out,
        "--intrinsics", solved["left"], solved["right"], "--min-rectified-fraction", "0.97",
    )  # fmt: skip
    assert run.returncode == 2 and not out.exists() and "Traceback" not in run.stderr
    line = run.stderr.strip().splitlines()[-1]
    assert "of the camera image (limit 97 %, --min-rectified-fraction)" in line
    assert "no rectification option keeps 97 %" in line  # nothing it could advise would
    assert "inconsistent" not in line and "same board poses" not in line  # the pairs fit
    assert "the joint solve (without --intrinsics) of the same views is refused too" in line
