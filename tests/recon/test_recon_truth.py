"""`vbfe reconstruct --truth`: Middlebury-style scores against ground truth (a rendered pair's
exact truth as PFM + calib.txt, and a real Middlebury pair scored as plain OpenCV would), and
disparity ranges SGBM cannot hold refused in one line."""

import re

import cv2
import numpy as np
import pytest

from tests import paths
from tests.cli import vbfe as _vbfe
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.recon import make_pattern
from vbfe.truth import calibration_from_rig

CONES = paths.DATA / "middlebury_cones"


def _scores(stdout: str) -> dict[str, list[float]]:
    """The printed score table: density, bad>1/2/3 (all, valid-only) in %, MAE px and mm."""
    density = float(re.search(r"density ([\d.]+)%\n", stdout)[1])
    rows = {
        name: [float(v) for v in re.search(rf"  {name} +([\d. ]+)\n", stdout)[1].split()]
        for name in ("all", "valid-only")
    }
    mae = re.search(r"mean abs error ([\d.]+) px, ([\d.]+) mm", stdout)
    return {"density": [density], **rows, "mae": [float(mae[1]), float(mae[2])]}


def _write_pfm(path, values):
    height, width = values.shape
    with open(path, "wb") as fh:
        fh.write(f"Pf\n{width} {height}\n-1.0\n".encode())
        fh.write(np.flipud(values).astype("<f4").tobytes())


def test_rendered_pair_scored_against_its_exact_truth_in_middlebury_files(tmp_path):
    rig = default_rig(640, 360, working_distance_m=0.06)
    rng = np.random.default_rng(2)
    pair = render_scene(
        rig,
        TissueSurface(distance_m=0.06, texture=tissue_texture(rng)),
        make_pattern(rig.projector.width, rig.projector.height),
        rng=rng,
    )
    cal = calibration_from_rig(rig)
    cv2.imwrite(str(tmp_path / "im0.png"), pair.left)
    cv2.imwrite(str(tmp_path / "im1.png"), pair.right)
    _write_pfm(
        tmp_path / "disp0.pfm",
        np.where(pair.valid_left, pair.disparity_left_px, np.inf).astype(np.float32),
    )
    (tmp_path / "calib.txt").write_text(
        f"cam0=[{cal.f} 0 {cal.cx}; 0 {cal.f} {cal.cy}; 0 0 1]\n"
        f"cam1=[{cal.f} 0 {cal.cx}; 0 {cal.f} {cal.cy}; 0 0 1]\n"
        f"doffs=0\nbaseline={cal.B * 1e3}\nwidth=640\nheight=360\nndisp=80\n"
    )
    result = _vbfe(
        "reconstruct",
        tmp_path / "im0.png",
        tmp_path / "im1.png",
        "--calib",
        tmp_path / "calib.txt",
        "--truth",
        tmp_path / "disp0.pfm",
    )
    assert result.returncode == 0, result.stderr
    scores = _scores(result.stdout)
    assert scores["density"][0] > 80
    assert scores["valid-only"][0] < 0.5 and scores["valid-only"][2] < 0.1  # bad>1, bad>3 %
    assert scores["all"][0] > scores["valid-only"][0]  # missing pixels count as bad in "all"
    assert scores["mae"][0] < 0.3 and scores["mae"][1] < 0.5  # px; mm: < 1 % of 60 mm


def test_real_middlebury_pair_scores_as_plain_opencv_sgbm(tmp_path):
    result = _vbfe(
        "reconstruct",
        CONES / "im0.png",
        CONES / "im1.png",
        "--rectified",
        "--f",
        1000,
        "--baseline",
        100,
        "--cx",
        150,
        "--cy",
        100,
        "--min-disparity",
        0,
        "--num-disparities",
        64,
        "--no-verify",
        "--truth",
        CONES / "disp0.png",
        "--truth-scale",
        4,
        "--out",
        tmp_path / "cones.clouds.h5",
    )
    assert result.returncode == 0, result.stderr
    scores = _scores(result.stdout)
    # the same matcher and scoring in plain OpenCV + numpy
    left, right = (
        cv2.imread(str(CONES / name), cv2.IMREAD_COLOR) for name in ("im0.png", "im1.png")
    )
    matcher = cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=64,
        blockSize=5,
        P1=8 * 3 * 25,
        P2=32 * 3 * 25,
        disp12MaxDiff=1,
        preFilterCap=63,
        uniquenessRatio=5,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    raw = matcher.compute(left, right)
    truth = cv2.imread(str(CONES / "disp0.png"), cv2.IMREAD_UNCHANGED) / 4.0
    known, matched = truth > 0, raw > 0
    error = np.abs(raw[known & matched] / 16.0 - truth[known & matched])
    n_known = known.sum()
    assert scores["density"][0] == pytest.approx(100 * error.size / n_known, abs=0.006)
    for k, t in enumerate((1, 2, 3)):
        bad = np.count_nonzero(error > t)
        assert scores["valid-only"][k] == pytest.approx(100 * bad / error.size, abs=0.006)
        assert scores["all"][k] == pytest.approx(
            100 * (bad + n_known - error.size) / n_known, abs=0.006
        )
    assert scores["mae"][0] == pytest.approx(error.mean(), abs=0.0006)


def test_disparity_range_sgbm_cannot_hold_is_one_line_exit_2(tmp_path):
    common = [
        "reconstruct",
        CONES / "im0.png",
        CONES / "im1.png",
        "--rectified",
        "--cx",
        150,
        "--cy",
        100,
        "--out",
        tmp_path / "x.clouds.h5",
    ]
    # a real Middlebury geometry with the rig's 25-120 mm depth range: ~24000 px of disparity
    result = _vbfe(*common, "--f", 3740, "--baseline", 160)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vbfe reconstruct: error: disparity range ")
    assert "--min-disparity/--num-disparities" in lines[0] and "Traceback" not in result.stderr
    result = _vbfe(*common, "--f", 1000, "--baseline", 100, "--num-disparities", 40)
    assert result.returncode == 2 and "multiple of 16" in result.stderr
    assert not (tmp_path / "x.clouds.h5").exists()
