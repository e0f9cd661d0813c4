"""Stereo calibration on the simulated bench: accuracy against the rig's truth, outlier corners,
left/right desynchronisation, failures with clear messages, the CLI and `calibrate check`."""

from __future__ import annotations

import functools
import json

import cv2
import numpy as np
import pytest

from vbfe.acquire import SessionWriter, finalize_session
from vbfe.calib.board import BoardDetector, BoardSpec, Detection
from vbfe.calib.calibration import Calibration, load_calibration
from vbfe.calib.check import check_calibration
from vbfe.calib.stereo import StereoOptions, calibrate_detections, calibrate_stereo, detect_views
from vbfe.calib.views import ViewSet, load_views, save_views
from vbfe.cli.main import main
from vbfe.common.errors import CalibrationError
from vbfe.drivers.samples import StereoFrame
from vbfe.drivers.sim.board_scene import DISTANCE_M
from vbfe.drivers.sim.charuco_scene import random_board_poses, render_board_views
from vbfe.drivers.sim.rig import default_rig

SPEC = BoardSpec()  # the default [calib] board: 9x7, 3 mm squares, DICT_5X5_100
N_VIEWS = 20


def rig_with_baseline(baseline_m: float = 0.004):
    return default_rig(640, 360, baseline_m=baseline_m, distortion=True)


def rendered(seed: int = 1, n: int = N_VIEWS, baseline_m: float = 0.004):
    """Views of the board at random poses, and the poses (cached: rendering is the slow part)."""
    return _rendered(seed, n, baseline_m)


@functools.cache
def _rendered(seed: int, n: int, baseline_m: float):
    rig = rig_with_baseline(baseline_m)
    rng = np.random.default_rng(seed)
    board = SPEC.board()
    poses = random_board_poses(n, rng, distance_m=DISTANCE_M, rig=rig, board=board)
    pairs = render_board_views(rig, board, poses, rng=rng)
    return ViewSet(pairs, [f"v{i:02d}" for i in range(n)], f"rendered seed {seed}"), poses


@functools.cache
def calibrated():
    views, _ = rendered()
    return calibrate_stereo(views, SPEC)


@functools.cache
def detections():
    views, _ = rendered()
    return tuple(detect_views(views, SPEC))


def relative(a: float, b: float) -> float:
    return abs(a / b - 1)


def test_twenty_random_views_recover_the_bench_geometry():
    rig = rig_with_baseline()
    result = calibrated()
    cal = result.calibration
    for K, camera in ((cal.K1, rig.left), (cal.K2, rig.right)):
        assert relative(K[0, 0], camera.K[0, 0]) < 0.005
        assert relative(K[1, 1], camera.K[1, 1]) < 0.005
        assert relative(K[0, 2], camera.K[0, 2]) < 0.005
        assert relative(K[1, 2], camera.K[1, 2]) < 0.005
    assert relative(cal.B, rig.baseline_m) < 0.01
    assert cal.rms_stereo_px < 0.5 and cal.rms_left_px < 0.5 and cal.rms_right_px < 0.5
    # rectified pair: rows agree, f/cx/cy are those of P1, B from P2
    assert cal.info["epipolar_rms_px"] < 0.3
    assert cal.f == pytest.approx(cal.P1[0, 0]) and cal.cx == pytest.approx(cal.P1[0, 2])
    assert cal.B == pytest.approx(-cal.P2[0, 3] / cal.P2[0, 0])
    # the stated uncertainty is a real (small, positive) number
    assert 0 < cal.info["depth_sigma_at_working_distance_m"] < 0.002
    assert cal.per_view_rms_px.shape == (len(result.names), 3)


def test_rectified_images_put_corners_on_the_same_row():
    views, _ = rendered()
    cal = calibrated().calibration
    detector = cv2.aruco.CharucoDetector(SPEC.board())
    left, right = cal.rectify(*views.pairs[3])
    cl, il, _, _ = detector.detectBoard(left)
    cr, ir, _, _ = detector.detectBoard(right)
    common, a, b = np.intersect1d(il.ravel(), ir.ravel(), return_indices=True)
    assert len(common) > 12
    dy = cl.reshape(-1, 2)[a, 1] - cr.reshape(-1, 2)[b, 1]
    assert np.sqrt(np.mean(dy**2)) < 0.3


def test_injected_outlier_corners_are_rejected_and_intrinsics_stay_accurate():
    views, _ = rendered()
    rig = rig_with_baseline()
    found = list(detections())
    rng = np.random.default_rng(7)
    injected = set()
    for v in range(0, N_VIEWS, 2):
        left, right = found[v]
        if len(left) < 20:
            continue
        corners = left.corners.copy()
        k = int(rng.integers(len(corners)))
        angle = rng.uniform(0, 2 * np.pi)
        corners[k] += 2.0 * np.array([np.cos(angle), np.sin(angle)])
        found[v] = (Detection(left.ids, corners), right)
        injected.add((views.names[v], "left", int(left.ids[k])))
    assert len(injected) >= 5
    result = calibrate_detections(found, views.names, (640, 360), SPEC)
    rejected = {(v, c, i) for v, c, i, _ in result.calibration.info["rejected_corners"]}
    assert injected <= rejected
    K = result.calibration.K1
    for got, true in (
        (K[0, 0], rig.left.K[0, 0]),
        (K[0, 2], rig.left.K[0, 2]),
        (K[1, 2], rig.left.K[1, 2]),
    ):
        assert relative(got, true) < 0.005
    # without rejection the 2-px corners pull the solution: the rejection is doing the work
    loose = calibrate_detections(
        found, views.names, (640, 360), SPEC, StereoOptions(outlier_sigma=1e6)
    )
    assert loose.calibration.rms_left_px > 1.5 * result.calibration.rms_left_px


def test_left_right_desync_is_detected_and_the_views_named():
    views, poses = rendered()
    rig = rig_with_baseline()
    board = SPEC.board()
    found = list(detections())
    detector = BoardDetector(SPEC)
    desynced = [2, 9, 15]
    for v in desynced:  # board moved 0.5 mm (15 mm/s, one 30 Hz frame) before the right exposure
        rvec, tvec = poses[v]
        moved = (rvec, np.asarray(tvec) + np.array([0.0004, 0.0003, 0.0]))
        ((_, right),) = render_board_views(rig, board, [moved], rng=np.random.default_rng(v))
        found[v] = (found[v][0], detector.detect(right))
    result = calibrate_detections(found, views.names, (640, 360), SPEC)
    assert set(result.desync) == {views.names[v] for v in desynced}
    assert set(result.desync) <= set(result.dropped)
    assert relative(result.calibration.B, rig.baseline_m) < 0.01
    assert sorted(result.calibration.info["desynchronised_views"]) == sorted(result.desync)


def test_no_board_found_names_the_board_options():
    views, _ = rendered()
    blank = [(np.full_like(left, 110), np.full_like(right, 110)) for left, right in views.pairs[:8]]
    with pytest.raises(CalibrationError, match="no ChArUco board found.*DICT_5X5_100"):
        calibrate_stereo(ViewSet(blank, views.names[:8], "blank"), SPEC)


def test_wrong_dictionary_names_the_one_seen():
    views, _ = rendered()
    wrong = BoardSpec(dictionary="DICT_4X4_50")
    subset = ViewSet(views.pairs[:6], views.names[:6], "subset")
    seen = r"no ChArUco board.*DICT_4X4_50 in the first 3 views.*use --dictionary DICT_5X5_50$"
    with pytest.raises(CalibrationError, match=seen):
        calibrate_stereo(subset, wrong)
    with pytest.raises(CalibrationError, match="unknown ArUco dictionary 'DICT_NOPE'"):
        calibrate_stereo(subset, BoardSpec(dictionary="DICT_NOPE"))


def test_too_few_views_says_how_many_and_which_were_dropped():
    views, _ = rendered()
    pairs = list(views.pairs[:5])
    pairs[4] = (np.full_like(pairs[4][0], 110), pairs[4][1])  # board not seen in the left eye
    with pytest.raises(
        CalibrationError, match=r"only 4 usable views, need at least 6.*v04: too few"
    ):
        calibrate_stereo(ViewSet(pairs, views.names[:5], "few"), SPEC)


def test_mixed_image_sizes_name_the_odd_view():
    views, _ = rendered()
    pairs = list(views.pairs[:7])
    pairs[5] = (cv2.resize(pairs[5][0], (320, 180)), cv2.resize(pairs[5][1], (320, 180)))
    with pytest.raises(CalibrationError, match=r"mixed image sizes.*640x360.*v05 \(320x180"):
        calibrate_stereo(ViewSet(pairs, views.names[:7], "mixed"), SPEC)


def test_cli_stereo_writes_yaml_and_report_and_session(tmp_path, capsys):
    views, _ = rendered()
    folder = tmp_path / "views"
    save_views(folder, views.pairs[:10], views.names[:10])
    session = tmp_path / "session.h5"
    writer = SessionWriter(session, (640, 360))
    writer.append_frames(
        [
            StereoFrame(left=left, right=right, seq=i, t_device_ns=i, t_host_ns=i)
            for i, (left, right) in enumerate(views.pairs[:2])
        ]
    )
    writer.close()
    finalize_session(session, {})
    out = tmp_path / "cal.yaml"
    assert (
        main(["calibrate", "stereo", str(folder), "-o", str(out), "--store-in", str(session)]) == 0
    )
    printed = capsys.readouterr().out
    assert "B " in printed and "mm" in printed
    cal = Calibration.load(out)
    assert cal.image_size == (640, 360) and len(cal.info["views"]) == 10
    assert (tmp_path / "cal.png").stat().st_size > 10_000
    assert "Stereo calibration" in (tmp_path / "cal.html").read_text()
    from_session = load_calibration(session)
    assert np.allclose(from_session.P2, cal.P2) and from_session.B == pytest.approx(cal.B)
    frames = load_views(session)  # sessions are a view source too
    assert len(frames) == 2 and np.array_equal(frames.pairs[1][0], views.pairs[1][0])


def test_cli_reports_a_missing_folder_as_one_line(tmp_path, capsys):
    assert main(["calibrate", "stereo", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert "nowhere does not exist" in err and "Traceback" not in err


def test_check_passes_an_unchanged_rig_and_fails_a_moved_baseline(tmp_path):
    stored = calibrated().calibration
    same, _ = rendered(seed=11, n=3)
    moved, _ = rendered(seed=11, n=3, baseline_m=0.004 * 1.02)
    ok = check_calibration(stored, views=same, spec=SPEC, max_depth_error_m=0.0005)
    bad = check_calibration(stored, views=moved, spec=SPEC, max_depth_error_m=0.0005)
    assert ok.passed and ok.depth_error_m < 0.0003 and ok.epipolar_rms_px < 0.3
    assert not bad.passed
    assert bad.depth_error_m == pytest.approx(0.02 * 0.06, rel=0.25)
    # parameter comparison: a calibration with a 2 % longer baseline is a NO-GO too
    longer = stored.replace(P2=stored.P2 * np.array([1, 1, 1, 1.02]))
    assert not check_calibration(stored, new=longer).passed
    assert check_calibration(stored, new=stored).passed
    # and through the CLI (exit 1 = NO-GO)
    path = stored.save(tmp_path / "stored.yaml")
    folder = tmp_path / "moved"
    save_views(folder, moved.pairs, moved.names)
    assert main(["calibrate", "check", str(path), "--views", str(folder)]) == 1
    save_views(tmp_path / "same", same.pairs, same.names)
    assert main(["calibrate", "check", str(path), "--views", str(tmp_path / "same")]) == 0


def test_calibration_yaml_records_provenance():
    info = calibrated().calibration.info
    text = json.dumps(info)
    assert info["board"]["dictionary"] == "DICT_5X5_100" and "created_utc" in text
