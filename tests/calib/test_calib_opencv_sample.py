"""OpenCV's own stereo chessboard sample (tests/data/opencv_stereo, 13 real pairs, 9x6): vbfe's
calibration and corners against plain OpenCV calls, as OpenCV's stereo_calib.cpp makes them."""

from __future__ import annotations

import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests import paths
from tests.cli import vbfe, vbfe_here
from vbfe.calib.board import BoardDetector, BoardSpec, Detection
from vbfe.calib.calibration import Calibration
from vbfe.calib.gates import GateLimits
from vbfe.calib.stereo import StereoOptions, calibrate_detections
from vbfe.common.config import read_toml

DATA = paths.DATA / "opencv_stereo"
VIEWS = [f"{i:02d}" for i in range(1, 15) if i != 10]  # stereo_calib.xml's list
INNER = (9, 6)
SPEC = BoardSpec(squares_x=10, squares_y=7, square_m=0.001, target="chessboard")
SUBPIX = (cv2.TERM_CRITERIA_MAX_ITER + cv2.TERM_CRITERIA_EPS, 30, 0.01)  # stereo_calib.cpp's


def _grey(eye: str, view: str) -> np.ndarray:
    return cv2.imread(str(DATA / f"{eye}{view}.jpg"), cv2.IMREAD_GRAYSCALE)


def _opencv_corners(grey: np.ndarray, half_window: int) -> np.ndarray:
    """stereo_calib.cpp's detection: findChessboardCorners, then cornerSubPix."""
    found, corners = cv2.findChessboardCorners(
        grey, INNER, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    assert found
    return cv2.cornerSubPix(grey, corners, (half_window, half_window), (-1, -1), SUBPIX)


@pytest.fixture(scope="module")
def opencv_reference() -> dict[str, float]:
    """Plain OpenCV: corners refined in an 11×11 window, initCameraMatrix2D, then one joint
    stereoCalibrate with default flags."""
    obj = np.zeros((INNER[0] * INNER[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0 : INNER[0], 0 : INNER[1]].T.reshape(-1, 2)
    left = [_opencv_corners(_grey("left", v), 5) for v in VIEWS]
    right = [_opencv_corners(_grey("right", v), 5) for v in VIEWS]
    objs, size = [obj] * len(VIEWS), (640, 480)
    K1 = cv2.initCameraMatrix2D(objs, left, size, 0)
    K2 = cv2.initCameraMatrix2D(objs, right, size, 0)
    rms, K1, _, K2, _, _, T, _, _ = cv2.stereoCalibrate(
        objs,
        left,
        right,
        K1,
        None,
        K2,
        None,
        size,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-5),
    )
    return {"rms": rms, "fx_left": K1[0, 0], "fx_right": K2[0, 0], "T": float(np.linalg.norm(T))}


# `vbfe calibrate stereo` on the OpenCV sample: a chessboard of 9x6 inner corners, squares of 1
CALIBRATE_SAMPLE = ("calibrate", "stereo", str(DATA), "--inner-corners", "9x6", "--square-mm", "1")


RIG = "# the lab's rig\n[calib]\nmin_views = 6  # kept as written\n"


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    """The sample calibrated with --settle into a rig file (``rig.toml`` beside ``c.yaml``)."""
    out = tmp_path_factory.mktemp("opencv_sample") / "c.yaml"
    rig = out.parent / "rig.toml"
    rig.write_text(RIG)
    settle = ("--settle", "--config", str(rig))
    return vbfe(*CALIBRATE_SAMPLE, "-o", str(out), *settle, timeout=120), out


def test_settle_keeps_the_calibration_and_its_board_in_the_rig_file(cli_run):
    run, out = cli_run
    rig = out.parent / "rig.toml"
    assert run.returncode == 0, run.stderr
    assert f"rig file {rig}: [calib] calibration = " in run.stdout
    calib = read_toml(rig, "rig")["calib"]
    assert calib["calibration"] == str(out.resolve())
    board = (calib["target"], calib["inner_corners"], calib["square_mm"])
    assert board == ("chessboard", [9, 6], 1)
    text = rig.read_text()
    assert "# the lab's rig" in text and "min_views = 6  # kept as written" in text
    (backup,) = out.parent.glob("rig.toml.*.bak")
    assert backup.read_text() == RIG


def test_the_sample_calibrates_through_the_cli_as_plain_opencv_does(cli_run, opencv_reference):
    run, out = cli_run
    assert run.returncode == 0, run.stderr
    cal = Calibration.load(out)
    assert cal.K1[0, 0] == pytest.approx(opencv_reference["fx_left"], rel=0.005)
    assert cal.K2[0, 0] == pytest.approx(opencv_reference["fx_right"], rel=0.005)
    assert np.linalg.norm(cal.T) * 1e3 == pytest.approx(opencv_reference["T"], rel=0.005)
    assert cal.rms_stereo_px < 1.2 * opencv_reference["rms"]
    assert cal.info["views"] == VIEWS and cal.info["dropped_views"] == {}


def test_corners_agree_with_opencv_on_every_real_image():
    """Within 0.1 px (mean per image) of findChessboardCorners + cornerSubPix in an 11×11
    window."""
    detector = BoardDetector(SPEC)
    worst = 0.0
    for view in VIEWS:
        for eye in ("left", "right"):
            grey = _grey(eye, view)
            ours = detector.detect(grey).corners
            theirs = _opencv_corners(grey, 5).reshape(-1, 2)
            if np.linalg.norm(ours[0] - theirs[0]) > np.linalg.norm(ours[0] - theirs[-1]):
                theirs = theirs[::-1]  # the same corners numbered from the other end
            worst = max(worst, float(np.linalg.norm(ours - theirs, axis=1).mean()))
    assert worst <= 0.1


def test_pair_05s_outlier_corner_is_rejected_and_views_numbered_apart_are_named():
    """stereo_calib.cpp refines in a 23×23 window, which pulls corner 45 of right05 3-4 px off
    (|dy| 3.8 px after rectification); fed those corners, vbfe rejects it by name. The right
    eyes of 02 and 07, numbered here from the other end, are renumbered and named."""
    detections = []
    for view in VIEWS:
        left, right = (
            _opencv_corners(_grey(eye, view), 11).reshape(-1, 2).astype(np.float64)
            for eye in ("left", "right")
        )
        ids = np.arange(len(left), dtype=np.int32)
        if view in ("02", "07"):
            right = right[::-1]
        detections.append((Detection(ids, left), Detection(ids, right)))
    result = calibrate_detections(
        detections, VIEWS, (640, 480), SPEC, StereoOptions(gates=GateLimits(nominal_baseline_m=0.0))
    )
    rejected = {
        (view, eye, corner): px
        for view, eye, corner, px in result.calibration.info["rejected_corners"]
    }
    assert rejected[("05", "right", 45)] > 2.0
    assert result.renumbered == ["02", "07"]


@pytest.mark.parametrize(
    "flag, value, says",
    [
        ("--min-views", "20", "only 13 usable views, need at least 20 (--min-views)"),
        ("--max-rms-px", "0.1", "is above the limit 0.1 px (--max-rms-px)"),
        ("--nominal-baseline-mm", "10", "% from the rig's nominal 10 mm (limit 25 %)"),
        (
            "--min-rectified-fraction",
            "0.99",
            "(limit 99 %, --min-rectified-fraction)",  # no free scaling keeps 99 %
        ),
        ("--min-baseline-mm", "100", "below the minimum 100 mm (--min-baseline-mm)"),
    ],
)
def test_gate_flags_refuse_naming_the_quantity_value_and_limit(tmp_path, capsys, flag, value, says):
    out = tmp_path / "c.yaml"
    run = vbfe_here(capsys, *CALIBRATE_SAMPLE, "-o", str(out), "--no-report", flag, value)
    assert run.returncode == 2 and not out.exists()
    error = run.stderr.strip().splitlines()[-1]
    assert error.startswith("vbfe calibrate: error:") and says in error


def test_check_uses_the_stored_board_and_working_distance_flag_and_cites_what_failed(
    cli_run, capsys
):
    _, calibration = cli_run
    go = vbfe_here(
        capsys,
        "calibrate",
        "check",
        str(calibration),
        "--views",
        str(DATA),
        "--working-distance-mm",
        "40",
    )
    assert go.returncode == 0, go.stderr
    assert "verdict at 40 mm     GO" in go.stdout
    no_go = vbfe_here(
        capsys,
        "calibrate",
        "check",
        str(calibration),
        "--views",
        str(DATA),
        "--max-epipolar-px",
        "0.05",
    )
    verdict = no_go.stdout.strip().splitlines()[-1]
    assert no_go.returncode == 1
    assert "NO-GO: epipolar RMS" in verdict and "limit 0.050 px" in verdict
    assert "depth error" not in verdict  # the depth error passed: it is not cited


def test_export_refuses_to_overwrite_without_the_flag(cli_run, tmp_path, capsys):
    _, calibration = cli_run
    args = (
        "calibrate",
        "export",
        str(calibration),
        "--format",
        "opencv",
        "--out-dir",
        str(tmp_path),
    )
    assert vbfe_here(capsys, *args).returncode == 0
    again = vbfe_here(capsys, *args)
    assert again.returncode == 2 and "--overwrite" in again.stderr
    assert vbfe_here(capsys, *args, "--overwrite").returncode == 0


def test_diagnostics_are_plain_yaml_and_the_board_is_the_chessboard(cli_run):
    _, calibration = cli_run
    text = calibration.read_text()
    assert "base64" not in text and "info_json" not in text
    fs = cv2.FileStorage(str(calibration), cv2.FILE_STORAGE_READ)
    board = fs.getNode("info").getNode("board")
    assert board.getNode("target").string() == "chessboard"
    assert (board.getNode("squares_x").real(), board.getNode("squares_y").real()) == (10, 7)
    assert board.getNode("dictionary").empty() and board.getNode("marker_m").empty()
    views = fs.getNode("info").getNode("views")
    assert [views.at(i).string() for i in range(views.size())] == VIEWS
    fs.release()


def test_the_report_shows_the_uncertainty_map_and_board_coverage(cli_run):
    run, out = cli_run
    cal = Calibration.load(out)
    uncertainty = cal.info["uncertainty"]
    sigma = np.array(uncertainty["depth_sigma_m"])
    assert np.isfinite(sigma).all() and (sigma > 0).all()
    centre = sigma[len(sigma) // 2, len(sigma[0]) // 2]
    assert centre < sigma[0, 0]  # known best mid-image
    # at the centre, close to the cruder σ(f), σ(B) estimate stored beside it
    assert 0.5 < centre / cal.info["depth_sigma_at_working_distance_m"] < 2
    # coverage: left images with corners in each third of the image, counted with OpenCV
    expected = np.zeros((3, 3), int)
    for view in VIEWS:
        corners = _opencv_corners(_grey("left", view), 5).reshape(-1, 2)
        regions = {(int(y * 3 // 480), int(x * 3 // 640)) for x, y in corners}
        for r, c in regions:
            expected[r, c] += 1
    assert uncertainty["board_views_per_region"] == expected.tolist()
    line = f"uncertainty                depth σ at 60 mm: {sigma[6, 8] * 1e3:.3f} mm centre"
    assert line in run.stdout and "board seen in every region" in run.stdout
    html = out.with_suffix(".html").read_text()
    assert "c_uncertainty.png" in html and uncertainty["summary"] in html
    assert out.with_name("c_uncertainty.png").stat().st_size > 10_000
