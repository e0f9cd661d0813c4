"""The calibration file format: round trips, wrong shapes, foreign files; printable boards."""

from __future__ import annotations

import dataclasses
import re

import cv2
import numpy as np
import pytest

from tests.calibration_nodes import STEREO_MATRICES
from vbfe.calib.board import BoardSpec
from vbfe.calib.calibration import Calibration, load_calibration
from vbfe.calib.camera import CameraOptions
from vbfe.calib.capture import CaptureOptions
from vbfe.calib.gates import GateLimits
from vbfe.calib.projector import ProjectorOptions
from vbfe.calib.projector_capture import GrayCaptureOptions
from vbfe.calib.stereo import StereoOptions
from vbfe.cli.main import main
from vbfe.common.config import default_config
from vbfe.common.errors import CalibrationError
from vbfe.drivers.sim.rig import default_rig
from vbfe.truth import calibration_from_rig


@pytest.fixture
def calibration() -> Calibration:
    cal = calibration_from_rig(default_rig(640, 360, distortion=True))
    return cal.replace(
        rms_left_px=0.11,
        per_view_rms_px=np.full((4, 3), 0.1),
        color_mixing=np.eye(3) * 1.1,
        color_offset=np.array([1.0, 2.0, 3.0]),
        info={"views": ["a", "b"], "sigma_B_m": 1e-5},
    )


def test_yaml_round_trip_keeps_every_field(tmp_path, calibration):
    path = calibration.save(tmp_path / "cal.yaml")
    back = Calibration.load(path)
    for name in (
        *STEREO_MATRICES,
        "K_proj",
        "D_proj",
        "R_proj",
        "T_proj",
        "per_view_rms_px",
        "color_mixing",
        "color_offset",
    ):
        assert np.allclose(getattr(back, name), getattr(calibration, name)), name
    assert back.image_size == (640, 360) and back.projector_size == (1024, 768)
    assert back.rms_left_px == pytest.approx(0.11) and np.isnan(back.rms_right_px)
    assert back.info == calibration.info
    assert (back.f, back.B, back.cx, back.cy) == pytest.approx(
        (calibration.f, calibration.B, calibration.cx, calibration.cy)
    )
    assert back.B == pytest.approx(0.004, rel=1e-9)
    # plain OpenCV can read it too (what a C++ tool or another lab would do)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert np.allclose(fs.getNode("P2").mat(), calibration.P2)
    assert fs.getNode("B").real() == pytest.approx(0.004)


def test_wrong_shape_in_the_file_names_the_field(tmp_path, calibration):
    text = calibration.to_yaml_text()
    # make K1 a 2x3 matrix
    broken = re.sub(
        r"K1: !!opencv-matrix\s+rows: 3\s+cols: 3\s+dt: d\s+data: \[[^\]]*\]",
        "K1: !!opencv-matrix\n   rows: 2\n   cols: 3\n   dt: d\n"
        "   data: [ 1., 0., 320., 0., 1., 180. ]",
        text,
    )
    assert broken != text
    path = tmp_path / "bad.yaml"
    path.write_text(broken)
    with pytest.raises(
        CalibrationError, match=r"bad.yaml.*K1 has shape \(2, 3\), expected \(3, 3\)"
    ):
        Calibration.load(path)


def test_missing_field_foreign_file_and_missing_file(tmp_path, calibration):
    text = calibration.to_yaml_text()
    no_q = re.sub(r"\nQ: !!opencv-matrix\s+rows: 4\s+cols: 4\s+dt: d\s+data: \[[^\]]*\]", "", text)
    (tmp_path / "noq.yaml").write_text(no_q)
    with pytest.raises(CalibrationError, match="noq.yaml has no Q"):
        Calibration.load(tmp_path / "noq.yaml")
    (tmp_path / "other.yaml").write_text("%YAML:1.0\n---\ncamera_matrix: 1\n")
    with pytest.raises(CalibrationError, match="not a vbfe calibration file"):
        load_calibration(tmp_path / "other.yaml")
    (tmp_path / "junk.yaml").write_text("{{{ not yaml")
    with pytest.raises(CalibrationError, match="junk.yaml is not OpenCV FileStorage YAML"):
        load_calibration(tmp_path / "junk.yaml")
    with pytest.raises(CalibrationError, match="nothere.yaml does not exist"):
        load_calibration(tmp_path / "nothere.yaml")


def test_rectify_refuses_images_of_another_size(calibration):
    small = np.zeros((180, 320, 3), np.uint8)
    with pytest.raises(CalibrationError, match="320x180.*640x360"):
        calibration.rectify(small, small)


def test_board_files_have_true_physical_size(tmp_path, capsys):
    assert (
        main(
            [
                "calibrate",
                "board",
                str(tmp_path / "board"),
                "--squares-x",
                "7",
                "--squares-y",
                "5",
                "--square-mm",
                "4",
                "--marker-mm",
                "3",
            ]
        )
        == 0
    )
    png = cv2.imread(str(tmp_path / "board.png"), cv2.IMREAD_GRAYSCALE)
    # 7x5 squares of 4 mm plus a 2 mm margin each side, at 40 px/mm
    assert png.shape == ((5 * 4 + 4) * 40, (7 * 4 + 4) * 40)
    pdf = (tmp_path / "board.pdf").read_bytes()
    box = [float(v) for v in re.search(rb"/MediaBox \[ *([\d. ]+)\]", pdf).group(1).split()]
    assert box[2] * 25.4 / 72 == pytest.approx(32.0, abs=0.05)  # mm
    assert box[3] * 25.4 / 72 == pytest.approx(24.0, abs=0.05)
    # the printed board is the one the detector expects
    spec = BoardSpec(7, 5, 0.004, 0.003)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(spec.board()).detectBoard(png)
    assert ids is not None and len(ids) == spec.n_corners


def test_board_with_bad_options_is_refused(tmp_path, capsys):
    assert main(["calibrate", "board", str(tmp_path / "b"), "--marker-mm", "3.5"]) == 2
    assert "must be smaller than the square" in capsys.readouterr().err
    assert (
        main(
            [
                "calibrate",
                "board",
                str(tmp_path / "b"),
                "--dictionary",
                "DICT_4X4_50",
                "--squares-x",
                "12",
                "--squares-y",
                "10",
            ]
        )
        == 2
    )
    assert "needs 60 markers but DICT_4X4_50 has only 50" in capsys.readouterr().err
    assert not (tmp_path / "b.png").exists()


def test_legacy_boards_need_the_legacy_option():
    from vbfe.calib.board import BoardDetector, board_image

    legacy = BoardSpec(8, 6, 0.004, 0.003, legacy=True)  # even rows: the layouts differ
    current = BoardSpec(8, 6, 0.004, 0.003)
    printed_long_ago = board_image(legacy, px_per_mm=10)
    assert len(BoardDetector(legacy).detect(printed_long_ago)) == legacy.n_corners
    assert len(BoardDetector(current).detect(printed_long_ago)) == 0
    assert BoardSpec.from_config({"legacy": True, "squares_x": 8}).board().getLegacyPattern()


def test_calibration_defaults_are_written_once_in_the_rig_table():
    """Every options field set by a [calib] key defaults to that key's value in
    default_rig.toml (in the field's units)."""
    table = default_config()["calib"]
    classes = [
        BoardSpec,
        CameraOptions,
        StereoOptions,
        GateLimits,
        CaptureOptions,
        ProjectorOptions,
        GrayCaptureOptions,
    ]
    checked = 0
    for cls in classes:
        for f in dataclasses.fields(cls):
            key = f.metadata.get("calib_key")
            if key is not None:
                default = f.default_factory() if f.default is dataclasses.MISSING else f.default
                scale = f.metadata["scale"]
                expected = table[key] if scale == 1.0 else pytest.approx(table[key] * scale)
                assert default == expected, (cls, f.name)
                checked += 1
    assert checked >= 30
    assert GateLimits().nominal_baseline_m == pytest.approx(table["nominal_baseline_mm"] * 1e-3)
