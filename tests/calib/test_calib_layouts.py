"""Folder layouts other labs use, made from OpenCV's stereo sample (tests/data/opencv_stereo):
MATLAB's left/leftNN + right/rightNN, eye folders with the same names, Kalibr's cam0/cam1 with
nanosecond stamps, ROS camera_calibration's left-0000/right-0000, OpenCV's stereo_calib image
list and a CSV of pairs pair the same images in the same order as the --left/--right globs, and
calibrate to the same numbers; what cannot pair is refused naming the files."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests import paths
from vbfe.calib.calibration import load_calibration
from vbfe.calib.views import load_views
from vbfe.cli.main import main
from vbfe.common.errors import CalibrationError

DATA = paths.DATA / "opencv_stereo"
VIEWS = [f"{i:02d}" for i in range(1, 15) if i != 10]
GLOBS = {"left_glob": str(DATA / "left*.jpg"), "right_glob": str(DATA / "right*.jpg")}
T0_NS = 1385030208726607500  # a Kalibr bagextractor stamp


def _copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)


def _layout(kind: str, root: Path) -> tuple[Path, dict]:
    """OpenCV's sample laid out as ``kind`` under ``root``: the source argument and the keyword
    arguments of :func:`load_views` that read it."""
    for k, view in enumerate(VIEWS):
        left, right = DATA / f"left{view}.jpg", DATA / f"right{view}.jpg"
        if kind == "eye_named_folders":  # MATLAB's Stereo Camera Calibrator layout
            _copy(left, root / "left" / left.name)
            _copy(right, root / "right" / right.name)
        elif kind == "same_names_folders":
            _copy(left, root / "L" / f"{view}.jpg")
            _copy(right, root / "R" / f"{view}.jpg")
        elif kind == "kalibr":  # 20 Hz, the right eye's stamp up to 1.5 ms off the left's
            t = T0_NS + k * 50_000_000
            _copy(left, root / "cam0" / f"{t}.jpg")
            _copy(right, root / "cam1" / f"{t + (k % 4) * 500_000}.jpg")
        elif kind == "ros":
            _copy(left, root / f"left-{k:04d}.jpg")
            _copy(right, root / f"right-{k:04d}.jpg")
        elif kind in ("image_list", "pairs_csv"):  # names no rule pairs
            _copy(left, root / "shots" / f"a{k:03d}.jpg")
            _copy(right, root / "shots" / f"b{k:03d}.jpg")
    if kind == "image_list":  # stereo_calib.xml's format
        names = " ".join(f'"shots/a{k:03d}.jpg" "shots/b{k:03d}.jpg"' for k in range(len(VIEWS)))
        (root / "stereo_calib.xml").write_text(
            f'<?xml version="1.0"?>\n<opencv_storage>\n<imagelist>\n{names}\n</imagelist>\n'
            "</opencv_storage>\n"
        )
        return root / "stereo_calib.xml", {}
    if kind == "pairs_csv":
        lines = [f"shots/a{k:03d}.jpg,shots/b{k:03d}.jpg" for k in range(len(VIEWS))]
        (root / "pairs.csv").write_text("left,right\n" + "\n".join(lines) + "\n")
        return root, {"pairs_file": root / "pairs.csv"}
    return root, {}


KINDS = ("eye_named_folders", "same_names_folders", "kalibr", "ros", "image_list", "pairs_csv")


@pytest.mark.parametrize("kind", KINDS)
def test_every_layout_pairs_the_same_images_in_the_same_order_as_the_globs(tmp_path, kind):
    source, kwargs = _layout(kind, tmp_path)
    views = load_views(source if not kwargs else None, **kwargs)
    reference = load_views(**GLOBS)
    assert len(views) == len(reference) == 13 and views.unpaired == []
    for (left, right), (left_ref, right_ref) in zip(views.pairs, reference.pairs, strict=True):
        assert np.array_equal(left, left_ref) and np.array_equal(right, right_ref)


def _stereo(*args: str) -> int:
    return main(["calibrate", "stereo", *args, "--inner-corners", "9x6", "--square-mm", "1"])


@pytest.mark.slow
def test_every_layout_calibrates_to_the_numbers_of_the_glob_form(tmp_path, capsys):
    reference = tmp_path / "glob.yaml"
    assert (
        _stereo(
            "--left",
            GLOBS["left_glob"],
            "--right",
            GLOBS["right_glob"],
            "-o",
            str(reference),
            "--no-report",
        )
        == 0
    )
    ref = load_calibration(reference)
    for kind in KINDS:
        source, kwargs = _layout(kind, tmp_path / kind)
        out = tmp_path / f"{kind}.yaml"
        args = ["--pairs", str(kwargs["pairs_file"])] if kwargs else [str(source)]
        assert _stereo(*args, "-o", str(out), "--no-report") == 0, capsys.readouterr().err
        cal = load_calibration(out)
        for name in ("K1", "D1", "K2", "D2", "R", "T", "P1", "P2"):
            assert np.allclose(getattr(cal, name), getattr(ref, name), rtol=1e-9, atol=1e-12), (
                kind,
                name,
            )
        assert cal.rms_stereo_px == pytest.approx(ref.rms_stereo_px, rel=1e-9)


def test_kalibr_stamps_pair_nearest_within_tolerance_and_unpaired_ones_are_listed(tmp_path):
    source, _ = _layout("kalibr", tmp_path)
    extra = T0_NS + len(VIEWS) * 50_000_000
    _copy(DATA / "right14.jpg", tmp_path / "cam1" / f"{extra}.jpg")  # no left frame near it
    _copy(DATA / "left14.jpg", tmp_path / "cam0" / f"{extra + 25_000_000}.jpg")  # 25 ms off
    views = load_views(source)
    assert len(views) == 13
    assert sorted(views.unpaired) == [f"cam0/{extra + 25_000_000}.jpg", f"cam1/{extra}.jpg"]
    assert views.names[0] == str(T0_NS)


def test_same_stem_twice_is_refused_with_the_names_or_chosen_by_ext(tmp_path, capsys):
    for view in VIEWS[:3]:
        for eye in ("left", "right"):
            _copy(DATA / f"{eye}{view}.jpg", tmp_path / f"{eye}{view}.jpg")
    image = cv2.imread(str(DATA / "left01.jpg"))
    cv2.imwrite(str(tmp_path / "left01.png"), 255 - image)
    with pytest.raises(CalibrationError) as err:
        load_views(tmp_path)
    message = str(err.value)
    assert "left01.jpg and left01.png have the same name" in message and "--ext" in message
    views = load_views(tmp_path, ext="jpg")
    assert views.names == VIEWS[:3] and np.array_equal(views.pairs[0][0], image)
    out = tmp_path / "c.yaml"
    assert _stereo(str(tmp_path), "-o", str(out)) == 2 and not out.exists()
    assert "left01.jpg and left01.png" in capsys.readouterr().err


def test_when_nothing_pairs_the_closest_rule_and_unmatched_names_are_shown(tmp_path):
    for k, view in enumerate(VIEWS[:5]):
        _copy(DATA / f"left{view}.jpg", tmp_path / "left" / f"img_{k}.jpg")
        _copy(DATA / f"right{view}.jpg", tmp_path / "right" / f"pic-{k + 1}.jpg")
    with pytest.raises(CalibrationError) as err:
        load_views(tmp_path)
    message = str(err.value)
    assert "closest rule, left/ + right/ same names, found 5 left and 5 right images" in message
    assert "img_0.jpg | pic-1.jpg; img_1.jpg | pic-2.jpg" in message
    assert "--pairs" in message and "\n" not in message


def test_a_bad_pairs_csv_names_the_line_or_the_missing_file(tmp_path):
    (tmp_path / "pairs.csv").write_text("a.png,b.png,c.png\n")
    _copy(DATA / "left01.jpg", tmp_path / "a.png")
    with pytest.raises(CalibrationError, match="line 1 has 3 fields"):
        load_views(pairs_file=tmp_path / "pairs.csv")
    (tmp_path / "pairs.csv").write_text("a.png,missing.png\n")
    with pytest.raises(CalibrationError, match="names missing.png, which is not a file"):
        load_views(pairs_file=tmp_path / "pairs.csv")


def test_help_lists_every_layout_and_every_gate_override():
    import sys

    text = subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", "calibrate", "stereo", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    for flag in (
        "--min-views",
        "--max-rms-px",
        "--min-baseline-mm",
        "--nominal-baseline-mm",
        "--baseline-tolerance",
        "--min-rectified-fraction",
        "--rectify-alpha",
        "--zero-disparity",
        "--pairs",
        "--ext",
        "--swap-eyes",
    ):
        assert flag in text, flag
    for layout in ("left/left01.png", "cam0/", "left-0000.png", "stereo_calib"):
        assert layout in " ".join(text.split()), layout
