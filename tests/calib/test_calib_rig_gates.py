"""Gates that fit the rig in front of you, on OpenCV's stereo sample (tests/data/opencv_stereo):
a nominal baseline only where stated, each gate in the report with its measured value, limit
and verdict, fixed intrinsics that solve and rectify as plain OpenCV does, rejected corners
named by eye, and a refused command that leaves no output."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests import paths
from vbfe.calib.board import BoardSpec
from vbfe.calib.calibration import load_calibration
from vbfe.calib.camera import points
from vbfe.calib.camera_model import CameraModel
from vbfe.calib.stereo import calibrate_stereo
from vbfe.calib.views import load_views
from vbfe.cli.main import main

DATA = paths.DATA / "opencv_stereo"
SPEC = BoardSpec(squares_x=10, squares_y=7, square_m=0.001, target="chessboard")
BOARD = ("--inner-corners", "9x6", "--square-mm", "1")


def _stereo(*args: str) -> int:
    return main(["calibrate", "stereo", str(DATA), *BOARD, *args])


@pytest.mark.slow  # three calibrations of the sample
def test_an_image_folder_is_not_the_bench_its_nominal_baseline_only_where_stated(tmp_path, capsys):
    out = tmp_path / "c.yaml"
    # 1.6 mm squares: B = 5.3 mm, 33 % beyond the built-in bench's 4 mm, which is not this rig
    assert _stereo("-o", str(out), "--square-mm", "1.6") == 0
    printed = capsys.readouterr().out
    cal = load_calibration(out)
    gates = {row[0]: row for row in cal.info["gates"]}
    assert gates["nominal baseline"][2:] == ["none stated (--nominal-baseline-mm)", "not checked"]
    assert [row[3] for row in cal.info["gates"]].count("pass") == 4
    assert "nominal baseline" in printed and "not checked" in printed
    html = out.with_suffix(".html").read_text()
    assert "Sanity gates" in html and "--min-rectified-fraction" in html
    # stated in the user's own rig file, it is checked
    (tmp_path / "rig.toml").write_text("[calib]\nnominal_baseline_mm = 4.0\n")
    out2 = tmp_path / "c2.yaml"
    args = ("-o", str(out2), "--square-mm", "1.6", "--config", str(tmp_path / "rig.toml"))
    assert _stereo(*args) == 2 and not out2.exists()
    assert "% from the rig's nominal 4 mm (limit 25 %)" in capsys.readouterr().err
    assert _stereo(*args, "--baseline-tolerance", "0.4") == 0
    gates = {row[0]: row for row in load_calibration(out2).info["gates"]}
    assert gates["nominal baseline"][2].startswith("4 mm ± 40 %")
    assert gates["nominal baseline"][3] == "pass"


def test_a_refused_command_leaves_no_output(tmp_path, capsys):
    not_a_session = tmp_path / "X.h5"
    not_a_session.write_bytes(b"not hdf5")
    out = tmp_path / "c.yaml"
    assert _stereo("-o", str(out), "--store-in", str(not_a_session)) == 2
    err = capsys.readouterr().err
    assert "X.h5" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["X.h5"]
    assert not_a_session.read_bytes() == b"not hdf5"
    # a report left by an earlier run is an output too: refused before any work
    out.with_suffix(".html").write_text("earlier report")
    assert _stereo("-o", str(out)) == 2
    assert "c.html" in capsys.readouterr().err and not out.exists()
    assert out.with_suffix(".html").read_text() == "earlier report"


def test_calibrate_camera_names_the_eye_of_rejected_corners(tmp_path, capsys):
    # a strict outlier limit, so that some corners of the real images are rejected
    (tmp_path / "rig.toml").write_text("[calib]\noutlier_sigma = 2.0\noutlier_min_px = 0.0\n")
    out = tmp_path / "right.yaml"
    args = ["calibrate", "camera", str(DATA), "--eye", "right", *BOARD, "-o", str(out)]
    assert main([*args, "--config", str(tmp_path / "rig.toml")]) == 0
    printed = capsys.readouterr().out
    rejected = [line for line in printed.splitlines() if "rejected corner" in line]
    assert rejected and all("(right eye)" in line for line in rejected)
    assert "camera eye" not in printed


def _camera_files(folder: Path) -> tuple[CameraModel, CameraModel]:
    """Each eye calibrated alone by `vbfe calibrate camera` (as a user fixes intrinsics)."""
    models = []
    for eye in ("left", "right"):
        out = folder / f"{eye}.yaml"
        assert main(["calibrate", "camera", str(DATA), "--eye", eye, *BOARD, "-o", str(out)]) == 0
        models.append(CameraModel.load(out))
    return models[0], models[1]


def test_fixed_intrinsics_solve_and_rectify_as_plain_opencv(tmp_path):
    left, right = _camera_files(tmp_path)
    result = calibrate_stereo(load_views(DATA), SPEC, intrinsics=(left, right))
    cal = result.calibration
    assert np.array_equal(cal.K1, left.K) and np.array_equal(cal.K2, right.K)
    # plain OpenCV on the same corners: stereoCalibrate(FIX_INTRINSIC) + stereoRectify
    obj, img_l = points(SPEC.object_points(), [p[0] for p in result.stereo_detections])
    _, img_r = points(SPEC.object_points(), [p[1] for p in result.stereo_detections])
    rms, *_, R, T, _, _ = cv2.stereoCalibrate(
        obj, img_l, img_r, left.K, left.D, right.K, right.D, (640, 480),
        flags=cv2.CALIB_FIX_INTRINSIC,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9),
    )  # fmt: skip
    assert np.allclose(cal.R, R, atol=1e-9) and np.allclose(cal.T, T.ravel(), atol=1e-9)
    assert cal.rms_stereo_px == pytest.approx(rms, rel=1e-6)
    R1, R2, _, P2, _, _, _ = cv2.stereoRectify(
        left.K, left.D, right.K, right.D, (640, 480), R, T, flags=cv2.CALIB_ZERO_DISPARITY,
    )  # fmt: skip
    assert np.allclose(cal.R1, R1, atol=1e-9) and np.allclose(cal.R2, R2, atol=1e-9)
    assert cal.B == pytest.approx(-P2[0, 3] / P2[0, 0], rel=1e-9)
    # no free scaling: the smaller fy, the eyes' principal rays at their principal points' mean
    assert cal.f == cal.fy == min(left.K[1, 1], right.K[1, 1]) and cal.doffs == 0
    rays = [P[:, :3] @ Rk[:, 2] for P, Rk in ((cal.P1, R1), (cal.P2, R2))]
    landed = np.mean([ray[:2] / ray[2] for ray in rays], axis=0)
    assert landed == pytest.approx((left.K[:2, 2] + right.K[:2, 2]) / 2, abs=1e-9)
    assert 0 <= cal.cx < 640 and 0 <= cal.cy < 480


@pytest.mark.slow  # two calibrations of the sample
def test_a_session_recorded_with_the_rig_is_checked_against_the_rigs_nominal_baseline(
    tmp_path, capsys
):
    from vbfe.acquire import SessionWriter, finalize_session
    from vbfe.drivers.samples import StereoFrame

    views = load_views(DATA)
    session = tmp_path / "rig.h5"
    writer = SessionWriter(session, (640, 480))
    writer.append_frames(
        [
            StereoFrame(left=left, right=right, seq=i, t_device_ns=i, t_host_ns=i)
            for i, (left, right) in enumerate(views.pairs)
        ]
    )
    writer.close()
    finalize_session(session, {})
    out = tmp_path / "c.yaml"
    # B = 5.3 mm: the configured rig (the bench, 4 mm ± 25 %) recorded the session, so its
    # nominal baseline applies, as it does not to the same images in a folder
    args = ["calibrate", "stereo", str(session), *BOARD[:2], "--square-mm", "1.6", "-o", str(out)]
    assert main([*args, "--no-report"]) == 2 and not out.exists()
    assert "from the rig's nominal 4 mm (limit 25 %)" in capsys.readouterr().err
    assert main([*args, "--no-report", "--nominal-baseline-mm", "0"]) == 0
