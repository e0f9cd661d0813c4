"""Board options that do not match the printed board are refused after a quick look at the first
views, naming the board seen (issue 56), through the real CLI on OpenCV's own sample images: the
stereo chessboard (9x6 inner corners) given by its squares or as a ChArUco board, and the ChArUco
tutorial photo (5x7 squares, DICT_6X6_250) given as a chessboard."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests import paths
from tests.calib_image_sets import SAMPLE
from tests.cli import vbfe

pytestmark = pytest.mark.slow  # the CLI in a subprocess, a few seconds each

CHARUCO_PHOTO = paths.DATA / "opencv_charuco" / "choriginal.jpg"


@pytest.fixture(scope="module")
def charuco_folder(tmp_path_factory) -> Path:
    """The ChArUco photo as one stereo pair (left01.jpg + right01.jpg)."""
    folder = tmp_path_factory.mktemp("charuco")
    for eye in ("left", "right"):
        shutil.copyfile(CHARUCO_PHOTO, folder / f"{eye}01.jpg")
    return folder


def _refused(folder: Path, tmp_path: Path, *board: str, command: str = "stereo") -> str:
    """The one error line of a refused calibration that wrote nothing."""
    out = tmp_path / "out.yaml"
    extra = ["--eye", "left"] if command == "camera" else []
    run = vbfe("calibrate", command, folder, *extra, *board, "-o", out, timeout=60)
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr and not out.exists()
    line = run.stderr.strip().splitlines()[-1]
    assert line.startswith("vbfe calibrate: error: no ")
    return line


def test_chessboard_given_by_its_squares_names_the_inner_corners(tmp_path):
    line = _refused(SAMPLE, tmp_path, "--target", "chessboard", "--inner-corners", "10x7")
    assert "in the first 3 views" in line  # stopped early, not after scanning all 13
    assert "found a chessboard of 9x6 inner corners in 3 of 3" in line
    assert "the board has 10x7 squares; use --inner-corners 9x6" in line


def test_chessboard_given_as_charuco_names_the_chessboard(tmp_path):
    line = _refused(
        SAMPLE, tmp_path, "--target", "charuco", "--squares-x", "10", "--squares-y", "7"
    )
    assert "in the first 3 views" in line
    assert "it is a chessboard, not a ChArUco board" in line
    assert line.endswith("use --target chessboard --inner-corners 9x6")


@pytest.mark.parametrize("command", ["stereo", "camera"])
def test_charuco_given_as_chessboard_names_the_charuco_board(charuco_folder, tmp_path, command):
    line = _refused(
        charuco_folder,
        tmp_path,
        "--target",
        "chessboard",
        "--inner-corners",
        "5x7",
        command=command,
    )
    assert "found a ChArUco board of 5x7 squares (DICT_6X6_50)" in line
    assert "use --target charuco --squares-x 5 --squares-y 7 --dictionary DICT_6X6_50" in line


def test_charuco_with_swapped_squares_and_another_dictionary(charuco_folder, tmp_path):
    board = ["--target", "charuco", "--square-mm", "4", "--marker-mm", "2"]
    line = _refused(charuco_folder, tmp_path, *board, "--squares-x", "7", "--squares-y", "5")
    assert "found a ChArUco board of 5x7 squares (DICT_6X6_50)" in line
    assert line.endswith("use --squares-x 5 --squares-y 7 --dictionary DICT_6X6_50")
    # the advice taken: the board is seen (refused later only for having one view)
    advised = ["--squares-x", "5", "--squares-y", "7", "--dictionary", "DICT_6X6_50"]
    run = vbfe("calibrate", "stereo", charuco_folder, *board, *advised, "-o", tmp_path / "c.yaml")
    assert run.returncode == 2 and "ChArUco board" not in run.stderr.strip().splitlines()[-1]
