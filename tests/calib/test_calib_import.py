"""`vbfe calibrate import`: OpenCV, Kalibr, ROS and Middlebury calibrations read back from what
`calibrate export` writes, through the sanity gates."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vbfe.calib.calibration import Calibration
from vbfe.cli.main import main
from vbfe.drivers.sim.rig import default_rig
from vbfe.truth import calibration_from_rig


@pytest.fixture(scope="module")
def calibration() -> Calibration:
    cal = calibration_from_rig(default_rig(640, 360, distortion=True))
    D1, D2 = cal.D1.copy(), cal.D2.copy()
    D1[4:] = D2[4:] = 0.0  # Kalibr's radtan holds k1, k2, p1, p2 only
    return cal.replace(D1=D1, D2=D2)


def _round_trip(tmp_path, calibration: Calibration, fmt: str, *extra: str) -> Calibration:
    source = calibration.save(tmp_path / "rig.yaml")
    assert (
        main(
            ["calibrate", "export", str(source), "--format", fmt, "--out-dir", str(tmp_path / fmt)]
        )
        == 0
    )
    files = sorted(str(p) for p in (tmp_path / fmt).iterdir())
    if fmt == "ros":
        files = [str(tmp_path / fmt / "rig_left.yaml"), str(tmp_path / fmt / "rig_right.yaml")]
    out = tmp_path / f"{fmt}.yaml"
    assert main(["calibrate", "import", *files, "-o", str(out), *extra]) == 0
    return Calibration.load(out)


@pytest.mark.parametrize("fmt", ["opencv", "kalibr", "ros"])
def test_camera_models_and_pose_round_trip(tmp_path, calibration, fmt):
    back = _round_trip(tmp_path, calibration, fmt)
    for name in ("K1", "K2", "R"):
        assert np.allclose(getattr(back, name), getattr(calibration, name), atol=1e-9), name
    for name in ("D1", "D2"):
        assert np.allclose(getattr(back, name)[:5], getattr(calibration, name)[:5], atol=1e-12)
    assert np.allclose(back.T, calibration.T, rtol=1e-9, atol=1e-15)
    assert back.image_size == calibration.image_size
    assert back.f == pytest.approx(calibration.f, rel=1e-6)
    assert back.B == pytest.approx(calibration.B, rel=1e-9)


def test_middlebury_calib_txt_round_trips_the_rectified_pair(tmp_path, calibration):
    shifted = Calibration.rectified(700.0, 702.5, 0.004, 320.0, 180.0, (640, 360), doffs=12.5)
    back = _round_trip(tmp_path, shifted, "middlebury")
    assert (back.f, back.fy, back.doffs, back.cx, back.cy) == pytest.approx(
        (700.0, 702.5, 12.5, 320.0, 180.0)
    )
    assert back.B == pytest.approx(0.004)
    # a point at 50 mm: d = f·B/z - doffs, and Q gives it back (with fy for y)
    u, v, z = 400.0, 250.0, 0.05
    d = back.f * back.B / z - back.doffs
    X = back.Q @ np.array([u, v, d, 1.0])
    assert X[:3] / X[3] == pytest.approx([(u - 320) * z / 700, (v - 180) * z / 702.5, z])


def test_opencv_xml_with_k_names_and_square_units(tmp_path, calibration):
    path = tmp_path / "stereo.xml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in (
        ("K1", calibration.K1),
        ("D1", calibration.D1),
        ("K2", calibration.K2),
        ("D2", calibration.D2),
        ("R", calibration.R),
        ("T", calibration.T / 0.002),
    ):  # in 2 mm squares, as OpenCV's sample
        fs.write(name, value)
    fs.release()
    out = tmp_path / "c.yaml"
    assert (
        main(
            [
                "calibrate",
                "import",
                str(path),
                "-o",
                str(out),
                "--image-size",
                "640x360",
                "--unit-mm",
                "2",
            ]
        )
        == 0
    )
    back = Calibration.load(out)
    assert np.allclose(back.T, calibration.T) and back.B == pytest.approx(calibration.B)


def test_import_refuses_what_the_gates_refuse_and_needs_a_size(tmp_path, calibration, capsys):
    far = Calibration.rectified(700.0, 700.0, 0.2, 320.0, 180.0, (640, 360))
    (tmp_path / "calib.txt").write_text(
        "cam0=[700 0 320; 0 700 180; 0 0 1]\ncam1=[700 0 320; 0 700 180; 0 0 1]\ndoffs=0\n"
        f"baseline={far.B * 1e3}\nwidth=640\nheight=360\n"
    )
    out = tmp_path / "c.yaml"
    # a nominal baseline is checked only where the user states one: on the command line ...
    args = ["calibrate", "import", str(tmp_path / "calib.txt"), "-o", str(out)]
    assert main([*args, "--nominal-baseline-mm", "4"]) == 2
    assert "nominal 4 mm (limit 25 %)" in capsys.readouterr().err and not out.exists()
    # ... or in the user's rig file; the built-in bench's 4 mm is not another tool's rig
    (tmp_path / "rig.toml").write_text("[calib]\nnominal_baseline_mm = 150.0\n")
    assert main([*args, "--config", str(tmp_path / "rig.toml")]) == 2
    assert "nominal 150 mm (limit 25 %)" in capsys.readouterr().err and not out.exists()
    assert main(args) == 0 and out.exists()
    fs = cv2.FileStorage(str(tmp_path / "m.yml"), cv2.FILE_STORAGE_WRITE)
    for name in ("M1", "D1", "M2", "D2", "R", "T"):
        fs.write(name, getattr(calibration, {"M1": "K1", "M2": "K2"}.get(name, name)))
    fs.release()
    assert (
        main(["calibrate", "import", str(tmp_path / "m.yml"), "-o", str(tmp_path / "m.yaml")]) == 2
    )
    assert "--image-size" in capsys.readouterr().err


def test_reconstruct_rectified_takes_fx_and_fy(tmp_path, capsys):
    from vbfe.recon.inputs import rectified_calibration

    cal = rectified_calibration(700.0, 710.0, 4.0, 320.0, 180.0, (640, 360), doffs_px=3.0)
    assert (cal.f, cal.fy, cal.doffs, cal.B) == pytest.approx((700.0, 710.0, 3.0, 0.004))
    for eye in ("left", "right"):
        cv2.imwrite(str(tmp_path / f"{eye}.png"), np.zeros((360, 640, 3), np.uint8))
    pair = [str(tmp_path / "left.png"), str(tmp_path / "right.png")]
    geometry = ["--baseline", "4", "--cx", "320", "--cy", "180"]
    assert main(["reconstruct", *pair, "--rectified", "--f", "700", "--fx", "700", *geometry]) == 2
    assert "not both --f and --fx/--fy" in capsys.readouterr().err
    assert main(["reconstruct", *pair, "--rectified", "--fx", "700", *geometry]) == 2
    assert "missing --f (or --fx and --fy)" in capsys.readouterr().err
