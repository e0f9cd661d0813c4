"""Calibration inputs: the common pair namings are recognised, globs pair in sorted order, a
side-by-side image splits into two eyes, and a folder that fits no rule says what the rules are."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests import paths
from vbfe.calib.views import NAMING_RULES, load_images, load_views
from vbfe.common.errors import CalibrationError
from vbfe.recon.inputs import find_pairs


def image(value: int, width: int = 16, height: int = 8) -> np.ndarray:
    """A small BGR image whose grey level identifies it."""
    return np.full((height, width, 3), value, np.uint8)


def write(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img)


LAYOUTS = {
    "suffix": [
        ("view_000_left.png", "view_000_right.png"),
        ("view_001_left.png", "view_001_right.png"),
    ],
    "prefix": [("left01.jpg", "right01.jpg"), ("left02.jpg", "right02.jpg")],
    "dash": [("a-Left.png", "a-Right.png"), ("b-Left.png", "b-Right.png")],
    "letters": [("L01.png", "R01.png"), ("L02.png", "R02.png")],
    "letter_suffix": [("img_L.png", "img_R.png"), ("shot_L.png", "shot_R.png")],
    "folders": [("left/01.png", "right/01.png"), ("left/02.png", "right/02.png")],
    "letter_folders": [("L/01.png", "R/01.png"), ("L/02.png", "R/02.png")],
}


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_common_pair_namings_are_found(tmp_path, layout):
    for k, (left, right) in enumerate(LAYOUTS[layout]):
        write(tmp_path / left, image(10 + 40 * k))
        write(tmp_path / right, image(30 + 40 * k))
    views = load_views(tmp_path)
    assert len(views) == 2
    for k, (left, right) in enumerate(views.pairs):  # sorted by view name, eyes not swapped
        assert left[0, 0, 0] == pytest.approx(10 + 40 * k, abs=2)
        assert right[0, 0, 0] == pytest.approx(30 + 40 * k, abs=2)
    pairs = find_pairs(tmp_path)  # reconstruct takes every folder calibrate takes, alike
    assert list(pairs.names) == views.names
    assert all(pairs.frame(k).left[0, 0, 0] == pytest.approx(10 + 40 * k, abs=2) for k in range(2))


def test_side_by_side_images_split_into_left_and_right(tmp_path):
    for k in range(3):
        write(tmp_path / f"frame{k}.png", np.hstack([image(20 + k), image(200 + k)]))
    views = load_views(tmp_path)
    assert views.names == ["frame0", "frame1", "frame2"]
    assert views.pairs[1][0].shape == (8, 16, 3)
    assert views.pairs[1][0][0, 0, 0] == 21 and views.pairs[1][1][0, 0, 0] == 201
    write(tmp_path / "odd.png", image(5, width=15))
    with pytest.raises(CalibrationError, match="15 px wide.*not a side-by-side pair"):
        load_views(tmp_path)


def test_left_and_right_globs_pair_in_sorted_order(tmp_path):
    for k in range(3):
        write(tmp_path / "cam_a" / f"{k:03d}.png", image(10 + k))
        write(tmp_path / "cam_b" / f"x{k:03d}.png", image(100 + k))
    views = load_views(
        left_glob=str(tmp_path / "cam_a" / "*.png"), right_glob=str(tmp_path / "cam_b" / "*.png")
    )
    assert [(left[0, 0, 0], right[0, 0, 0]) for left, right in views.pairs] == [
        (10, 100),
        (11, 101),
        (12, 102),
    ]
    write(tmp_path / "cam_b" / "x003.png", image(103))
    with pytest.raises(CalibrationError, match="matches 3 images and --right .* 4"):
        load_views(
            left_glob=str(tmp_path / "cam_a" / "*.png"),
            right_glob=str(tmp_path / "cam_b" / "*.png"),
        )


def test_an_unpaired_view_is_named_with_the_naming_rules(tmp_path):
    write(tmp_path / "left01.png", image(1))
    write(tmp_path / "right01.png", image(2))
    write(tmp_path / "left02.png", image(3))
    with pytest.raises(CalibrationError) as err:
        load_views(tmp_path)
    assert "views without their other eye: 02" in str(err.value)
    assert NAMING_RULES in str(err.value) and "\n" not in str(err.value)


def test_single_camera_images_from_a_folder_a_glob_or_one_eye(tmp_path):
    for k in range(2):
        write(tmp_path / "mono" / f"img{k}.png", image(50 + k))
        write(tmp_path / "pairs" / f"left{k}.png", image(10 + k))
        write(tmp_path / "pairs" / f"right{k}.png", image(90 + k))
    assert load_images(tmp_path / "mono").names == ["img0", "img1"]
    assert len(load_images(str(tmp_path / "mono" / "img*.png"))) == 2
    right = load_images(tmp_path / "pairs", eye="right")
    assert [img[0, 0, 0] for img in right.images] == [90, 91]
    with pytest.raises(CalibrationError, match="holds stereo image pairs.*--eye left"):
        load_images(tmp_path / "pairs")


def test_naming_rules_are_in_the_help_and_the_manual():
    import subprocess
    import sys

    help_text = subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", "calibrate", "stereo", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
    ).stdout
    flat = " ".join(help_text.split())
    assert "left<name>.png + right<name>.png" in flat and "--left GLOB" in flat
    guide = (paths.REPO / "docs/how-to/calibrate.md").read_text(encoding="utf-8")
    assert "left01.jpg" in guide and "calibrate camera" in guide
