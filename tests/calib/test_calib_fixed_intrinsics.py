"""Fixed intrinsics against the joint solve (issue 56), through the real CLI: each eye's
intrinsics from `calibrate camera` on a weaker set of views, then `calibrate stereo --intrinsics`
beside the joint solve of the same pairs. Two proxies of the labs' endoscopes: OpenCV's stereo
sample with the right eye shifted 85 px in x (each image padded on one side, as a digitiser that
samples the two channels' lines from different starts crops them; the first 9 views for each
eye), and bench renders of the SD endoscope as the labs measured theirs
(vbfe.truth.endoscope.barrel_endoscope_rig: fx/fy 1.05, 85 px apart, k1 -0.3, eyes 0.7° apart;
each eye from 10 other views). Done when: the rectified f and B within 0.2 % of the joint
solve's, RMS within 10 %, the rectified image kept at least the gate's limit."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.calib_image_sets import VIEWS, sharp
from tests.cli import vbfe
from vbfe.calib.calibration import Calibration, load_calibration
from vbfe.calib.gates import GateLimits
from vbfe.calib.rectify import rectified_fractions
from vbfe.truth.endoscope import barrel_endoscope_rig, write_sd_endoscope_views

pytestmark = pytest.mark.slow  # renders and calibrations in subprocesses: about a minute each
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


def _solve(folder: Path, weak: dict[str, tuple], board: tuple[str, ...], out: Path):
    """The joint solve of ``folder``, each eye's camera file from ``calibrate camera`` of its
    ``weak`` views (the command's arguments) and the fixed-intrinsics solve: their paths."""
    files = {"joint": out / "joint.yaml", "fixed": out / "fixed.yaml"}
    run = vbfe("calibrate", "stereo", folder, *board, "--no-report", "-o", files["joint"])
    assert run.returncode == 0, run.stderr
    for eye in ("left", "right"):
        files[eye] = out / f"{eye}.yaml"
        run = vbfe("calibrate", "camera", *weak[eye], *board, "-o", files[eye])
        assert run.returncode == 0, run.stderr
    run = vbfe(
        "calibrate", "stereo", folder, *board, "--no-report", "-o", files["fixed"],
        "--intrinsics", files["left"], files["right"],
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    return files


@pytest.fixture(scope="module")
def solved(shifted, tmp_path_factory) -> dict[str, Path]:
    """The shifted sample's solves; each eye's camera file from views 01-09."""
    weak = {eye: (shifted / eye / f"{eye}0*.png",) for eye in ("left", "right")}
    return _solve(shifted, weak, BOARD, tmp_path_factory.mktemp("solved"))


@pytest.fixture(scope="module", params=["9x6", "7x7"])
def barrel(request, tmp_path_factory) -> dict[str, Path]:
    """The barrel endoscope's solves: 20 views, each eye's camera file from 10 other views."""
    inner = tuple(int(n) for n in request.param.split("x"))
    out = tmp_path_factory.mktemp(f"barrel_{request.param}")
    rig = barrel_endoscope_rig()
    write_sd_endoscope_views(out / "views", inner, 3.0, 20, seed=300, rig=rig)
    write_sd_endoscope_views(out / "weak", inner, 3.0, 10, seed=600, rig=rig)
    board = ("--inner-corners", request.param, "--square-mm", "3")
    weak = {eye: (out / "weak", "--eye", eye) for eye in ("left", "right")}
    return _solve(out / "views", weak, board, out)


def _kept(cal) -> float:
    return min(
        min(rectified_fractions(K, D, R, P, cal.image_size))
        for K, D, R, P in ((cal.K1, cal.D1, cal.R1, cal.P1), (cal.K2, cal.D2, cal.R2, cal.P2))
    )


def assert_agrees(joint: Calibration, fixed: Calibration) -> None:
    """Issue 56's bounds: the rectified f and B within 0.2 % of the joint solve's, stereo RMS
    within 10 %, both rectifications keeping the gate's limit, every gate passed."""
    assert fixed.f / joint.f == pytest.approx(1, abs=2e-3)
    assert fixed.B / joint.B == pytest.approx(1, abs=2e-3)
    assert fixed.rms_stereo_px / joint.rms_stereo_px == pytest.approx(1, abs=0.1)
    limit = GateLimits().min_rectified_fraction
    assert _kept(fixed) >= limit and _kept(joint) >= limit
    assert {row[3] for row in fixed.info["gates"]} == {"pass", "not checked"}


def test_fixed_intrinsics_agree_with_the_joint_solve(solved):
    joint, fixed = load_calibration(solved["joint"]), load_calibration(solved["fixed"])
    assert fixed.K2[0, 2] - fixed.K1[0, 2] == pytest.approx(joint.K2[0, 2] - joint.K1[0, 2], abs=2)
    assert joint.K2[0, 2] - joint.K1[0, 2] > SHIFT_PX - 25  # the sample's own offset is -15 px
    for K_fixed, K_joint in ((fixed.K1, joint.K1), (fixed.K2, joint.K2)):
        assert np.diag(K_fixed)[:2] / np.diag(K_joint)[:2] == pytest.approx([1, 1], abs=2e-3)
    assert_agrees(joint, fixed)


def test_fixed_intrinsics_on_the_barrel_endoscope_agree_with_the_joint_solve(barrel):
    joint, fixed = load_calibration(barrel["joint"]), load_calibration(barrel["fixed"])
    assert joint.K1[1, 1] / joint.K1[0, 0] == pytest.approx(1 / 1.05, abs=2e-3)  # as rendered
    assert joint.D1[0] == pytest.approx(-0.3, abs=0.01)
    assert_agrees(joint, fixed)


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
