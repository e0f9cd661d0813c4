"""Plain chessboard sets rendered on the simulated bench (known truth), calibrated through the
real CLI: stereo and single camera accuracy, fixed intrinsics, the robust solve (a bad view
dropped by name, a half-pixel corner kept), sanity gates (identical eyes, zero-baseline file)
and bad board parameters."""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.cli import vbfe, vbfe_here
from vbfe.calib.board import BoardDetector, BoardSpec, Detection
from vbfe.calib.calibration import Calibration
from vbfe.calib.camera_model import CameraModel
from vbfe.calib.chessboard import is_clear, same_numbering
from vbfe.calib.stereo import calibrate_detections, detect_views
from vbfe.calib.views import ViewSet
from vbfe.drivers.sim.charuco_scene import (
    ChessboardPattern,
    random_board_poses,
    render_board_views,
    render_mono_views,
)
from vbfe.drivers.sim.rig import default_rig

INNER = (9, 6)
SQUARE_M = 0.003
SPEC = BoardSpec(
    squares_x=INNER[0] + 1, squares_y=INNER[1] + 1, square_m=SQUARE_M, target="chessboard"
)
BOARD_ARGS = ["--inner-corners", f"{INNER[0]}x{INNER[1]}", "--square-mm", str(SQUARE_M * 1e3)]
RIG = default_rig(640, 360, baseline_m=0.004, distortion=True)
PATTERN = ChessboardPattern(INNER, SQUARE_M)
DISTANCE_M = (0.035, 0.07)


def error_lines(stderr: str) -> list[str]:
    """stderr without the progress bars."""
    return [
        line
        for line in stderr.replace("\r", "\n").splitlines()
        if line.strip()
        and "view/s]" not in line
        and "image/s]" not in line
        and "s/view]" not in line
        and "s/image]" not in line
        and "?view" not in line
        and "?image" not in line
    ]


@functools.cache
def stereo_set(seed: int = 0, n: int = 12) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    rng = np.random.default_rng(seed)
    poses = random_board_poses(
        n, rng, distance_m=DISTANCE_M, rig=RIG, board=PATTERN, min_visible=1.0
    )
    return tuple(render_board_views(RIG, PATTERN, poses, rng=rng))


@functools.cache
def mono_set(seed: int, n: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    poses = random_board_poses(
        n, rng, distance_m=DISTANCE_M, max_tilt_deg=40.0, rig=RIG, board=PATTERN, min_visible=1.0
    )
    return tuple(render_mono_views(RIG.left, PATTERN, poses, rng=rng))


def write_pairs(folder: Path, pairs, same_eyes: bool = False) -> Path:
    """Pairs as left01.png / right01.png (OpenCV's stereo sample naming)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, (left, right) in enumerate(pairs, start=1):
        cv2.imwrite(str(folder / f"left{i:02d}.png"), left)
        cv2.imwrite(str(folder / f"right{i:02d}.png"), left if same_eyes else right)
    return folder


def relative(got: float, true: float) -> float:
    return abs(got / true - 1)


def assert_intrinsics_within(K: np.ndarray, camera, tolerance: float) -> None:
    for (i, j), what in (((0, 0), "fx"), ((1, 1), "fy"), ((0, 2), "cx"), ((1, 2), "cy")):
        assert relative(K[i, j], camera.K[i, j]) < tolerance, (
            f"{what} {K[i, j]:.3f} vs true {camera.K[i, j]:.3f}"
        )


@pytest.fixture(scope="module")
def stereo_run(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    """`calibrate stereo` on the rendered set saved as left01.png / right01.png ..."""
    tmp = tmp_path_factory.mktemp("stereo")
    folder = write_pairs(tmp / "pairs", stereo_set())
    out = tmp / "calib.yaml"
    return vbfe("calibrate", "stereo", str(folder), "-o", str(out), "--no-report", *BOARD_ARGS), out


def test_chessboard_stereo_set_through_the_cli_recovers_the_bench(stereo_run):
    run, out = stereo_run
    assert run.returncode == 0, run.stderr
    cal = Calibration.load(out)
    assert_intrinsics_within(cal.K1, RIG.left, 0.005)
    assert_intrinsics_within(cal.K2, RIG.right, 0.005)
    assert relative(cal.B, RIG.baseline_m) < 0.01
    assert cal.info["board"]["target"] == "chessboard"
    assert len(cal.info["views"]) == 12 and not cal.info["dropped_views"]
    assert "σ(f)" in run.stdout and "σ(cx)" in run.stdout


def test_single_camera_and_fixed_intrinsics_stereo(stereo_run, tmp_path, capsys):
    folder = stereo_run[1].parent / "pairs"
    cams = {}
    for eye, camera in (("left", RIG.left), ("right", RIG.right)):
        path = tmp_path / f"{eye}.yaml"
        cli = vbfe if eye == "left" else functools.partial(vbfe_here, capsys)
        run = cli("calibrate", "camera", str(folder), "--eye", eye, "-o", str(path), *BOARD_ARGS)
        assert run.returncode == 0, run.stderr
        cams[eye] = CameraModel.load(path)
        assert_intrinsics_within(cams[eye].K, camera, 0.005)
        assert cams[eye].per_view_rms_px.shape == (12,) and cams[eye].rms_px < 0.2
        assert np.all(cams[eye].std_intrinsics[:4] > 0)
    # the camera files fix the intrinsics of a later stereo solve (CALIB_FIX_INTRINSIC)
    out = tmp_path / "fixed.yaml"
    run = vbfe_here(
        capsys,
        "calibrate",
        "stereo",
        str(folder),
        "-o",
        str(out),
        "--no-report",
        "--intrinsics",
        str(tmp_path / "left.yaml"),
        str(tmp_path / "right.yaml"),
        *BOARD_ARGS,
    )
    assert run.returncode == 0, run.stderr
    cal = Calibration.load(out)
    assert np.array_equal(cal.K1, cams["left"].K) and np.array_equal(cal.D2, cams["right"].D)
    assert relative(cal.B, RIG.baseline_m) < 0.01
    # a camera file of another resolution is refused with one line
    small = CameraModel(cams["left"].K, cams["left"].D, (320, 180))
    small.save(tmp_path / "small.yaml")
    run = vbfe_here(
        capsys,
        "calibrate",
        "stereo",
        str(folder),
        "-o",
        str(tmp_path / "x.yaml"),
        "--intrinsics",
        str(tmp_path / "small.yaml"),
        str(tmp_path / "right.yaml"),
        *BOARD_ARGS,
    )
    assert run.returncode == 2 and "320x180" in error_lines(run.stderr)[-1]


def wobble(image: np.ndarray, amplitude_px: float = 1.2, period_px: float = 45.0) -> np.ndarray:
    """The image with a smooth non-projective wave (a bent board, rolling-shutter wobble)."""
    h, w = image.shape[:2]
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    map_x = u + amplitude_px * np.sin(2 * np.pi * v / period_px)
    map_y = v + amplitude_px * np.cos(2 * np.pi * u / period_px)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def test_few_views_with_a_bad_one_drop_it_by_name_and_state_the_uncertainty(tmp_path):
    images = list(mono_set(seed=5, n=6))
    images[2] = wobble(images[2])
    folder = tmp_path / "mono"
    folder.mkdir()
    for i, image in enumerate(images):
        cv2.imwrite(str(folder / f"img{i}.png"), image)
    config = tmp_path / "rig.toml"
    config.write_text("[calib]\nmin_views = 4\n")
    out = tmp_path / "cam.yaml"
    run = vbfe(
        "calibrate", "camera", str(folder), "-o", str(out), "--config", str(config), *BOARD_ARGS
    )
    assert run.returncode == 0, run.stderr
    assert "dropped img2: camera per-view RMS" in run.stdout
    assert "weakly determined: only 5 views" in run.stdout
    model = CameraModel.load(out)
    assert model.views == ["img0", "img1", "img3", "img4", "img5"]
    assert model.dropped[0].startswith("img2: camera per-view RMS")
    # the intrinsics lie within the stated σ (3σ) of the truth, and σ is not vacuous
    true = RIG.left.K
    sigma = model.std_intrinsics[:4]
    got = np.array([model.K[0, 0], model.K[1, 1], model.K[0, 2], model.K[1, 2]])
    want = np.array([true[0, 0], true[1, 1], true[0, 2], true[1, 2]])
    assert np.all(np.abs(got - want) <= 3 * sigma), (got - want, sigma)
    assert np.all(sigma < 0.01 * want)


@functools.cache
def stereo_detections() -> tuple:
    pairs = stereo_set()
    views = ViewSet(list(pairs), [f"v{i:02d}" for i in range(len(pairs))], "rendered")
    return tuple(detect_views(views, SPEC)), views.names


def test_a_half_pixel_corner_is_kept_and_a_two_pixel_corner_rejected():
    found, names = stereo_detections()
    for shift, expect_rejected in ((0.5, False), (2.0, True)):
        dets = list(found)
        left, right = dets[4]
        corners = left.corners.copy()
        corners[20] += shift * np.array([0.6, 0.8])
        dets[4] = (Detection(left.ids, corners), right)
        result = calibrate_detections(dets, names, (640, 360), SPEC)
        rejected = {(v, c, i) for v, c, i, _ in result.calibration.info["rejected_corners"]}
        assert (("v04", "left", 20) in rejected) is expect_rejected
        assert not result.dropped and len(result.names) == len(names)
        if not expect_rejected:
            assert not rejected
        assert_intrinsics_within(result.calibration.K1, RIG.left, 0.005)


def test_identical_left_and_right_images_are_refused_naming_the_baseline(tmp_path):
    folder = write_pairs(tmp_path / "same", stereo_set()[:8], same_eyes=True)
    out = tmp_path / "cal.yaml"
    run = vbfe("calibrate", "stereo", str(folder), "-o", str(out), *BOARD_ARGS)
    assert run.returncode == 2
    lines = error_lines(run.stderr)
    assert len(lines) == 1 and lines[0].startswith("vbfe calibrate: error:")
    assert "baseline 0.0000 mm is below the minimum 0.5 mm" in lines[0]
    assert "nothing written" in lines[0] and not out.exists()


def test_check_says_no_go_for_a_zero_baseline_file_whatever_it_is_compared_with(
    stereo_run, tmp_path, capsys
):
    good = Calibration.load(stereo_run[1])
    P2 = good.P2.copy()
    P2[0, 3] = 0.0
    bad = good.replace(T=np.zeros(3), P2=P2).save(tmp_path / "zero.yaml")
    for stored, against in ((bad, bad), (bad, stereo_run[1]), (stereo_run[1], bad)):
        run = vbfe_here(capsys, "calibrate", "check", str(stored), "--against", str(against))
        assert run.returncode == 1, run.stderr
        assert "NO-GO" in run.stdout and "baseline 0.0000 mm is below the minimum" in run.stdout
    run = vbfe_here(
        capsys, "calibrate", "check", str(stereo_run[1]), "--against", str(stereo_run[1])
    )
    assert run.returncode == 0 and "GO" in run.stdout and "NO-GO" not in run.stdout


@pytest.mark.parametrize(
    "args, names",
    [
        (["--marker-mm", "0"], "marker size 0 mm (--marker-mm): must be a positive length"),
        (["--square-mm", "-3"], "square size -3 mm (--square-mm): must be a positive length"),
        (["--squares-x", "1"], "ChArUco board of 1x7 squares"),
        (["--marker-mm", "3"], "marker size 3 mm (--marker-mm) must be smaller than the square"),
        (["--inner-corners", "2x6"], "chessboard with 2x6 inner corners"),
        (["--inner-corners", "nine"], "--inner-corners 'nine': give the inner corners as NXxNY"),
    ],
)
def test_bad_board_parameters_are_one_line_and_exit_2(tmp_path, capsys, args, names):
    run = vbfe_here(
        capsys, "calibrate", "stereo", str(tmp_path), "-o", str(tmp_path / "c.yaml"), *args
    )
    assert run.returncode == 2
    lines = error_lines(run.stderr)
    assert len(lines) == 1 and lines[0].startswith("vbfe calibrate: error:"), run.stderr
    assert names in lines[0]


def test_a_bad_board_parameter_from_the_shell_is_one_line_and_exit_2(tmp_path):
    run = vbfe("calibrate", "camera", str(tmp_path), "--marker-mm", "0")
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr.strip().splitlines() == [
        "vbfe calibrate: error: marker size 0 mm (--marker-mm): must be a positive length, "
        "e.g. 2.2 for 3 mm squares"
    ]


def test_capture_collects_chessboard_views(tmp_path):
    from vbfe.calib.capture import ViewCollector

    collector = ViewCollector(SPEC)
    verdicts = [collector.offer(left, right) for left, right in stereo_set()[:4]]
    assert verdicts[0].kept and len(collector.pairs) >= 2
    assert len(verdicts[0].left) == INNER[0] * INNER[1]
    blank = np.full_like(stereo_set()[0][0], 110)
    refused = collector.offer(blank, blank)
    assert not refused.kept and "board not seen" in refused.reason
    left, right = stereo_set()[5]  # smeared over 5 px as by a board moving during the exposure
    blurred = collector.offer(cv2.blur(left, (5, 1)), cv2.blur(right, (5, 1)))
    assert not blurred.kept and blurred.reason.startswith("blurred")


def test_a_right_eye_numbered_from_the_other_end_is_renumbered_to_match_the_left():
    left, right = stereo_set()[0]
    detector = BoardDetector(SPEC)
    dl, dr = detector.detect(left), detector.detect(right)
    assert len(dl) == len(dr) == INNER[0] * INNER[1]
    kept, turned, contrast = same_numbering(dl.corners, dr.corners, INNER)
    assert not turned and is_clear(contrast) and np.array_equal(kept, dr.corners)
    back, turned, contrast = same_numbering(dl.corners, dr.corners[::-1], INNER)
    assert turned and is_clear(contrast) and np.array_equal(back, dr.corners)
    # a square board may also come numbered a quarter turn round
    square = (INNER[1], INNER[1])
    left_sq, right_sq = (
        d.corners.reshape(INNER[1], INNER[0], 2)[:, : INNER[1]].reshape(-1, 2) for d in (dl, dr)
    )
    quarter = np.rot90(right_sq.reshape(INNER[1], INNER[1], 2)).reshape(-1, 2)
    back, turned, contrast = same_numbering(left_sq, quarter, square)
    assert turned and is_clear(contrast) and np.array_equal(back, right_sq)
