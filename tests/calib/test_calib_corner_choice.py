"""Corners as accurate as OpenCV's best detector on every view (issue 40) and detectors that
see dark images (issue 45): `vbfe calibrate stereo` / `camera` on OpenCV's stereo sample as
shipped, shrunk and blurred, and darkened with noise and JPEG, against every plain OpenCV
pipeline (tests/plain_opencv.py) on the same images."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests import calib_image_sets as sets
from tests import plain_opencv
from tests.cli import vbfe_here
from vbfe.calib.board import BoardDetector, BoardSpec
from vbfe.calib.calibration import Calibration
from vbfe.calib.camera_model import CameraModel
from vbfe.calib.edge_width import edge_width_px
from vbfe.drivers.sim.charuco_scene import (
    ChessboardPattern,
    random_board_poses,
    render_board_views,
    render_mono_views,
)
from vbfe.drivers.sim.rig import default_rig

BOARD_ARGS = ["--inner-corners", "9x6", "--square-mm", str(sets.SQUARE_MM)]
SPEC = BoardSpec(squares_x=10, squares_y=7, square_m=sets.SQUARE_MM * 1e-3, target="chessboard")
# `vbfe calibrate stereo` on the sample at commit 7dd0dd9 (before the per-view choice):
# fx, fy of K1 and K2 (px) and |T| (mm)
TODAY = {"K1": (533.5573, 533.5632), "K2": (537.1288, 536.7085), "T_mm": 3.327562}


@functools.cache
def reference(name: str) -> dict[str, plain_opencv.PlainStereo]:
    return plain_opencv.all_stereo(sets.SETS[name](), sets.INNER, sets.SQUARE_MM * 1e-3)


def calibrate(capsys, tmp_path: Path, name: str) -> Calibration:
    folder = (
        sets.SAMPLE if name == "sharp" else sets.write_pairs(tmp_path / name, sets.SETS[name]())
    )
    out = tmp_path / f"{name}.yaml"
    run = vbfe_here(capsys, "calibrate", "stereo", str(folder), "-o", str(out), *BOARD_ARGS)
    assert run.returncode == 0, run.stderr
    return Calibration.load(out)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(sets.SETS))
def test_stereo_fits_as_well_as_the_best_plain_opencv_pipeline(capsys, tmp_path, name):
    cal = calibrate(capsys, tmp_path, name)
    assert cal.info["views"] == sets.VIEWS and cal.info["dropped_views"] == {}  # 13/13 kept
    results = reference(name)
    pipeline, best = plain_opencv.best(results)
    summary = {p: (r.n_pairs, round(r.rms, 3)) for p, r in results.items()}
    assert cal.rms_stereo_px <= 1.02 * best.rms, (cal.rms_stereo_px, pipeline, summary)
    assert np.linalg.norm(cal.T) == pytest.approx(best.T_norm, rel=0.003), (pipeline, summary)
    for eye, key in (("left", "rms_left"), ("right", "rms_right")):
        pipeline, best = plain_opencv.best(results, key)
        assert getattr(cal, key + "_px") <= 1.02 * getattr(best, key), (eye, pipeline, summary)
    # the report's per-view record: every kept view and eye, with a finite blur and residual
    rows = cal.info["corners"]
    assert sorted((r[0], r[1]) for r in rows) == sorted(
        (v, eye) for v in sets.VIEWS for eye in ("left", "right")
    )
    assert all(np.isfinite(r[4]) and 0 < r[5] < 1 for r in rows)
    counted = cal.info["views_per_detector"]
    assert sum(counted["finder"].values()) == sum(counted["method"].values()) == 26
    if name == "sharp":  # within 0.1 % of the calibration before the per-view choice
        for key, (fx, fy) in (("K1", TODAY["K1"]), ("K2", TODAY["K2"])):
            K = getattr(cal, key)
            assert K[0, 0] == pytest.approx(fx, rel=0.001) and K[1, 1] == pytest.approx(
                fy, rel=0.001
            )
        assert np.linalg.norm(cal.T) * 1e3 == pytest.approx(TODAY["T_mm"], rel=0.001)


@pytest.mark.slow
def test_camera_on_the_dark_set_fits_as_well_as_the_best_plain_pipeline(capsys, tmp_path):
    folder = sets.write_pairs(tmp_path / "dark", sets.dark())
    out = tmp_path / "left.yaml"
    run = vbfe_here(
        capsys, "calibrate", "camera", str(folder), "--eye", "left", "-o", str(out), *BOARD_ARGS
    )
    assert run.returncode == 0, run.stderr
    model = CameraModel.load(out)
    assert model.views == sets.VIEWS
    pipeline, best = plain_opencv.best(reference("dark"), "rms_left")
    assert model.rms_px <= 1.02 * best.rms_left, (model.rms_px, pipeline)
    assert "views per detector" in run.stdout and "edge width" in run.stdout


def test_every_dark_image_is_found_and_offers_each_refinement():
    """The darkened sample (mean grey 20, σ 3, JPEG): the board is found in the images and each
    detection carries the adaptive and OpenCV-sized windows' corners and the edge lines'
    crossings, numbered alike."""
    detector = BoardDetector(SPEC, candidates=True)
    labels = set()
    for pair in sets.dark()[:4]:
        for grey in pair:
            det = detector.detect(grey)
            assert len(det) == 54
            labels |= {c.label for c in det.candidates}
            for c in det.candidates:  # one numbering (a large window may pull a corner)
                gaps = np.linalg.norm(c.corners - det.corners, axis=1)
                assert np.median(gaps) < 1.0, c.label  # the spacing is 20-37 px
    assert {"cornerSubPix half 5", "cornerSubPix half 8", "cornerSubPix half 11"} <= labels
    assert "edge lines" in labels


def test_edge_width_measures_the_blur_added_to_an_image():
    """A Gaussian of σ added to the image widens the measured 10-90 % edge width as
    sqrt(w0² + (2.563 σ)²) predicts (to 15 %)."""
    grey = sets.sharp()[0][0]
    det = BoardDetector(SPEC).detect(grey)
    w0 = edge_width_px(grey, det.ids, det.corners, 9)
    assert 1.0 < w0 < 4.0
    for sigma in (2.0, 3.0):
        blurred = cv2.GaussianBlur(grey, (0, 0), sigma)
        width = edge_width_px(blurred, det.ids, det.corners, 9)
        assert width == pytest.approx(np.hypot(w0, 2.563 * sigma), rel=0.15)


@functools.cache
def endoscope_pairs() -> sets.Pairs:
    return sets.endoscope(n=8, seed=3)


@pytest.mark.slow
def test_endoscope_renders_fit_as_well_as_the_best_plain_pipeline_and_the_truth(capsys, tmp_path):
    """1080p renders through soft optics (defocus σ 2 px, vignetting, shot and read noise,
    JPEG), corners 16-25 px apart: OpenCV's 11×11 window loses to the sector detector as on the
    real laparoscope set of issue 40, and vbfe keeps up with the best pipeline and the truth."""
    pairs = endoscope_pairs()
    names = [f"{i:02d}" for i in range(len(pairs))]
    folder = sets.write_pairs(tmp_path / "endoscope", pairs, names)
    out = tmp_path / "endoscope.yaml"
    nx, ny = sets.ENDOSCOPE_INNER
    run = vbfe_here(
        capsys,
        "calibrate",
        "stereo",
        str(folder),
        "-o",
        str(out),
        "--no-report",
        "--inner-corners",
        f"{nx}x{ny}",
        "--square-mm",
        str(sets.ENDOSCOPE_SQUARE_MM),
    )
    assert run.returncode == 0, run.stderr
    cal = Calibration.load(out)
    results = plain_opencv.all_stereo(pairs, sets.ENDOSCOPE_INNER, sets.ENDOSCOPE_SQUARE_MM * 1e-3)
    rig = sets.endoscope_rig()
    summary = {
        p: (r.n_pairs, round(r.rms, 3), f"{r.T_norm / rig.baseline_m - 1:+.3%}")
        for p, r in results.items()
    }
    print("endoscope renders: vbfe", cal.rms_stereo_px, cal.B / rig.baseline_m - 1, summary)
    assert results["subpix5"].rms > 1.3 * results["sb_accuracy"].rms  # the failure reproduced
    pipeline, best = plain_opencv.best(results)
    assert len(cal.info["views"]) == best.n_pairs and not cal.info["dropped_views"]
    assert cal.rms_stereo_px <= 1.02 * best.rms, (cal.rms_stereo_px, pipeline, summary)
    assert np.linalg.norm(cal.T) == pytest.approx(best.T_norm, rel=0.003), (pipeline, summary)
    # against the truth, as issue 40 asks: f and B within 0.05 % (the sector detector's corners
    # made them 0.1 % off, see test_edge_line_corners_have_no_scale_bias_on_a_blurred_board)
    for K, camera in ((cal.K1, rig.left), (cal.K2, rig.right)):
        assert K[0, 0] == pytest.approx(camera.K[0, 0], rel=0.0005)
        assert K[1, 1] == pytest.approx(camera.K[1, 1], rel=0.0005)
    assert cal.B == pytest.approx(rig.baseline_m, rel=0.0005)


def _scale(corners: np.ndarray, truth: np.ndarray) -> float:
    """The relative scale about the board's centre that best maps ``truth`` onto ``corners``,
    minus 1 (after the mean shift)."""
    errors = corners - truth - (corners - truth).mean(axis=0)
    spread = truth - truth.mean(axis=0)
    return float(np.sum(errors * spread) / np.sum(spread * spread))


def test_edge_line_corners_have_no_scale_bias_on_a_blurred_board():
    """A noise-free 1080p render through the endoscope optics' blur and vignetting (σ 2 px
    defocus), the board tilted: the edge lines' crossings are within 0.02 px RMS of the true
    corners and scale the board by less than 0.003 %, where the sector detector's ACCURACY
    corners are over 0.1 px off and scale it by +0.05 % (which a per-view pose absorbs: the
    reason they are not among the candidates)."""
    rig = sets.endoscope_rig()
    pattern = ChessboardPattern(sets.ENDOSCOPE_INNER, sets.ENDOSCOPE_SQUARE_MM * 1e-3)
    optics = dataclasses.replace(sets.ENDOSCOPE_OPTICS, shot_noise=0, noise_sigma=0, jpeg_quality=0)
    rng = np.random.default_rng(0)
    pose = random_board_poses(
        1, rng, distance_m=(0.055, 0.085), max_tilt_deg=45.0, rig=rig, board=pattern, min_visible=1
    )[0]
    grey = render_mono_views(rig.left, pattern, [pose], optics=optics, supersample=2, rng=rng)
    grey = grey[0][..., 0]
    R_board, _ = cv2.Rodrigues(pose[0])
    truth = rig.left.project(
        pattern.getChessboardCorners().astype(np.float64) @ R_board.T + pose[1]
    )
    nx, ny = sets.ENDOSCOPE_INNER
    spec = BoardSpec(
        squares_x=nx + 1, squares_y=ny + 1, square_m=pattern.square_m, target="chessboard"
    )

    def numbered_as_truth(corners: np.ndarray) -> np.ndarray:
        grid = corners.reshape(ny, nx, 2)
        turns = [np.rot90(grid, k).reshape(-1, 2) for k in (0, 2)]
        return min(turns, key=lambda c: np.abs(c - truth).max())

    def rms(corners: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((corners - truth) ** 2, axis=1))))

    found = BoardDetector(spec, candidates=True).detect(grey)
    crossings = numbered_as_truth(
        next(c.corners for c in found.candidates if c.label == "edge lines")
    )
    assert rms(crossings) < 0.02 and abs(_scale(crossings, truth)) < 3e-5
    ok, sector = cv2.findChessboardCornersSB(grey, (nx, ny), flags=cv2.CALIB_CB_ACCURACY)
    assert ok
    sector = numbered_as_truth(sector.reshape(-1, 2).astype(np.float64))
    assert rms(sector) > 0.1 and _scale(sector, truth) > 4e-4


def test_a_square_board_is_numbered_one_way_in_every_eye_and_view():
    """A 7×7 board rolled up to ±40° in front of the bench's endoscope: every detection numbers
    the corners as the same turn of the board's own numbering (never a mirror), in both eyes."""
    rig = default_rig(640, 360, baseline_m=0.004, distortion=True)
    pattern = ChessboardPattern((7, 7), 0.003)
    rng = np.random.default_rng(7)
    poses = random_board_poses(
        6, rng, distance_m=(0.04, 0.06), max_roll_deg=40.0, rig=rig, board=pattern, min_visible=1.0
    )
    spec = BoardSpec(squares_x=8, squares_y=8, square_m=0.003, target="chessboard")
    detector = BoardDetector(spec)
    board_points = pattern.getChessboardCorners().astype(np.float64)
    turns = set()
    for pose, pair in zip(poses, render_board_views(rig, pattern, poses, rng=rng), strict=True):
        R_board, _ = cv2.Rodrigues(pose[0])
        points = board_points @ R_board.T + pose[1]
        for image, camera, R, T in (
            (pair[0], rig.left, None, None),
            (pair[1], rig.right, rig.R, rig.T),
        ):
            truth = camera.project(points, R, T).reshape(7, 7, 2)
            found = detector.detect(image).corners
            gaps = {
                (k, mirrored): np.abs(
                    np.rot90(truth.transpose(1, 0, 2) if mirrored else truth, k).reshape(-1, 2)
                    - found
                ).max()
                for k in range(4)
                for mirrored in (False, True)
            }
            match = min(gaps, key=gaps.get)
            assert gaps[match] < 0.5
            turns.add(match)
    assert len(turns) == 1 and not next(iter(turns))[1], turns


def test_boards_too_dim_for_both_detectors_are_found_after_a_contrast_stretch():
    """The sample at mean grey 3 (σ 1 noise, JPEG 70): each board is found whole, some only
    after the contrast stretch, which the detection names; each corner is the sharp image's
    (a median gap of 1.5 px at most: 8 grey levels and noise leave no finer corners; the
    spacing is 20-37 px)."""
    detector = BoardDetector(SPEC)
    finders = []
    for k, (grey, _) in enumerate(sets.sharp()[:6]):
        rng = np.random.default_rng(k)
        dim = grey.astype(np.float32) * (3.0 / grey.mean()) + rng.normal(0, 1.0, grey.shape)
        dim = np.clip(np.rint(dim), 0, 255).astype(np.uint8)
        dim = cv2.imdecode(cv2.imencode(".jpg", dim, [cv2.IMWRITE_JPEG_QUALITY, 70])[1], 0)
        found = BoardDetector(SPEC, candidates=True).detect(dim)
        assert len(found) == 54
        sharp = detector.detect(grey).corners
        assert np.median(np.linalg.norm(found.corners - sharp, axis=1)) < 1.5
        finders.append(found.finder)
    assert any(f.endswith("(contrast stretched)") for f in finders), finders
