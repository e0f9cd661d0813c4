"""`vbfe calibrate export`: ROS camera_info, Kalibr camchain and OpenCV files read back by
independent parsers (PyYAML, cv2.FileStorage) hold the calibration's K, D, R, P and T."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml

from vbfe.calib.calibration import Calibration
from vbfe.cli.main import main
from vbfe.drivers.sim.rig import default_rig


def calibration(k3: float = 0.0) -> Calibration:
    """A rig-like calibration (rotated right eye, distortion) rectified by OpenCV."""
    rig = default_rig(640, 360, baseline_m=0.004, distortion=True)
    R, _ = cv2.Rodrigues(np.array([0.002, -0.01, 0.003]))
    T = np.array([-0.004, 0.0001, 0.00005])
    D1 = rig.left.dist.copy()
    D1[4] = k3
    D2 = rig.right.dist.copy()
    size = (640, 360)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        rig.left.K,
        D1,
        rig.right.K,
        D2,
        size,
        R,
        T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0,
    )
    return Calibration(
        K1=rig.left.K,
        D1=D1,
        K2=rig.right.K,
        D2=D2,
        R=R,
        T=T,
        R1=R1,
        R2=R2,
        P1=P1,
        P2=P2,
        Q=Q,
        image_size=size,
        rms_left_px=0.1,
        rms_right_px=0.1,
        rms_stereo_px=0.1,
    )


def export(path, fmt: str) -> subprocess.CompletedProcess:
    """`vbfe calibrate export` in a subprocess."""
    return subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", "calibrate", "export", str(path), "--format", fmt],
        capture_output=True,
        text=True,
        timeout=120,
    )


def export_here(capsys, path, fmt: str) -> subprocess.CompletedProcess:
    """`vbfe calibrate export` through the CLI entry point in this process."""
    code = main(["calibrate", "export", str(path), "--format", fmt])
    out = capsys.readouterr()
    return subprocess.CompletedProcess([], code, out.out, out.err)


def matrix(node: dict) -> np.ndarray:
    return np.array(node["data"], np.float64).reshape(node["rows"], node["cols"])


def test_ros_camera_info_files_hold_k_d_r_p(tmp_path):
    cal = calibration()
    path = cal.save(tmp_path / "rig.yaml")
    run = export(path, "ros")
    assert run.returncode == 0, run.stderr
    for eye, K, D, R, P in (
        ("left", cal.K1, cal.D1, cal.R1, cal.P1),
        ("right", cal.K2, cal.D2, cal.R2, cal.P2),
    ):
        info = yaml.safe_load((tmp_path / f"rig_{eye}.yaml").read_text())
        assert (info["image_width"], info["image_height"]) == (640, 360)
        assert info["camera_name"] == eye and info["distortion_model"] == "plumb_bob"
        assert np.array_equal(matrix(info["camera_matrix"]), K)
        assert np.array_equal(matrix(info["distortion_coefficients"]), D.reshape(1, 5))
        assert np.array_equal(matrix(info["rectification_matrix"]), R)
        assert np.array_equal(matrix(info["projection_matrix"]), P)
    P2 = matrix(yaml.safe_load((tmp_path / "rig_right.yaml").read_text())["projection_matrix"])
    assert P2[0, 3] == pytest.approx(-cal.f * cal.B)  # ROS: Tx = -fx' * B


def test_kalibr_camchain_holds_intrinsics_distortion_and_t_cn_cnm1(tmp_path, capsys):
    cal = calibration()
    path = cal.save(tmp_path / "rig.yaml")
    run = export_here(capsys, path, "kalibr")
    assert run.returncode == 0, run.stderr
    chain = yaml.safe_load((tmp_path / "rig-camchain.yaml").read_text())
    for cam, K, D in (("cam0", cal.K1, cal.D1), ("cam1", cal.K2, cal.D2)):
        c = chain[cam]
        assert c["camera_model"] == "pinhole" and c["distortion_model"] == "radtan"
        assert c["intrinsics"] == [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
        assert np.array_equal(c["distortion_coeffs"], D[:4]) and c["resolution"] == [640, 360]
    T = np.array(chain["cam1"]["T_cn_cnm1"])
    assert T.shape == (4, 4) and np.array_equal(T[:3, :3], cal.R)
    assert np.array_equal(T[:3, 3], cal.T) and np.array_equal(T[3], [0, 0, 0, 1])
    assert "T_cn_cnm1" not in chain["cam0"]


def test_kalibr_refuses_a_k3_it_cannot_hold_and_opencv_files_read_back(tmp_path, capsys):
    cal = calibration(k3=0.01)
    path = cal.save(tmp_path / "rig.yaml")
    run = export_here(capsys, path, "kalibr")
    assert run.returncode == 2 and "k3 = 0.01" in run.stderr and "--fix-k3" in run.stderr
    assert not (tmp_path / "rig-camchain.yaml").exists()
    run = export_here(capsys, path, "opencv")
    assert run.returncode == 0, run.stderr
    fs = cv2.FileStorage(str(tmp_path / "intrinsics.yml"), cv2.FILE_STORAGE_READ)
    assert np.array_equal(fs.getNode("M1").mat(), cal.K1)
    assert np.array_equal(fs.getNode("D1").mat().ravel(), cal.D1)
    fs.release()
    fs = cv2.FileStorage(str(tmp_path / "extrinsics.yml"), cv2.FILE_STORAGE_READ)
    for name in ("R", "P1", "P2", "Q"):
        assert np.array_equal(fs.getNode(name).mat(), getattr(cal, name))
    assert np.array_equal(fs.getNode("T").mat().ravel(), cal.T)
    fs.release()
