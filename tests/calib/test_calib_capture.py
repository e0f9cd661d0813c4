"""`calibrate capture` on the simulated bench (its camera showing the board scene, read through
the camera driver): only sharp views at new poses are kept, coverage is tracked, the kept views
calibrate."""

from __future__ import annotations

import numpy as np

from vbfe.calib import commands
from vbfe.calib.board import BoardSpec
from vbfe.calib.capture import ViewCollector, coverage_text
from vbfe.calib.views import load_views
from vbfe.cli.main import main
from vbfe.drivers.sim.board_scene import motion_blur
from vbfe.drivers.sim.charuco_scene import render_board_views
from vbfe.drivers.sim.rig import default_rig
from vbfe.rig_config import builtin_rig
from vbfe.truth import board_config, true_rig

SPEC = BoardSpec()
RIG = default_rig(640, 360, distortion=True)
BOARD_RIG = '[bench]\nscene = "board"\n'


def _facing_pose(x_m: float, y_m: float, z_m: float, tilt_deg: float = 0.0):
    import cv2

    R, _ = cv2.Rodrigues(np.radians([tilt_deg, 0.0, 0.0]))
    centre = np.array([x_m, y_m, z_m])
    return cv2.Rodrigues(R)[0].ravel(), centre - R @ np.array([0.0135, 0.0105, 0.0])


def test_blurred_and_repeated_views_are_refused_and_new_ones_kept():
    rng = np.random.default_rng(0)
    poses = [_facing_pose(0.0, 0.0, 0.05), _facing_pose(-0.01, 0.004, 0.045, 25.0)]
    (a_left, a_right), (b_left, b_right) = render_board_views(RIG, SPEC.board(), poses, rng=rng)
    ((a2_left, a2_right),) = render_board_views(RIG, SPEC.board(), poses[:1], rng=rng)
    collector = ViewCollector(SPEC)
    assert collector.offer(a_left, a_right).kept
    still = collector.offer(a2_left, a2_right)  # same pose, new sensor noise
    assert not still.kept and "too close" in still.reason
    # a 3-px diagonal smear: corners are still found, but they would be biased
    blurred = collector.offer(motion_blur(b_left, 3, 30.0), motion_blur(b_right, 3, 30.0))
    assert not blurred.kept and "blurred" in blurred.reason, blurred.reason
    empty = collector.offer(np.full_like(a_left, 110), a_right)
    assert not empty.kept and "board not seen" in empty.reason
    assert collector.offer(b_left, b_right).kept
    coverage = collector.coverage()
    assert 0 < coverage["x"] < 1 and 0 < coverage["skew"] <= 1
    assert "views   2" in coverage_text(coverage, len(collector.pairs))


def test_capture_from_the_simulated_bench_saves_pairs_that_calibrate(tmp_path):
    config = board_config(builtin_rig(), seed=4, board_p_blur=0.2)
    config = config.updated({"calib": {"capture_views": 8, "capture_max_views": 8}})
    updates = []
    result = commands.capture(
        config,
        tmp_path / "views",
        max_frames=24,
        on_view=lambda verdict, collector, left: updates.append(verdict.kept),
    )
    assert result.enough and len(result.names) == 8 and sum(updates) == 8
    assert result.frames_seen == len(updates) <= 24
    assert sum(result.rejections.values()) == result.frames_seen - 8
    assert set(result.rejections) <= {
        "blurred",
        "pose too close to a kept view",
        "board not seen in both eyes",
    }
    views = load_views(tmp_path / "views")
    assert views.names == result.names
    from vbfe.calib.stereo import calibrate_stereo

    cal = calibrate_stereo(views, SPEC).calibration
    assert abs(cal.B / true_rig(config).baseline_m - 1) < 0.02
    # resuming into the same folder keeps the old views and numbers new ones after them
    config = config.updated({"calib": {"capture_views": 10, "capture_max_views": 10}})
    more = commands.capture(config, tmp_path / "views", max_frames=6, seed=9)
    assert all(int(n.split("_")[1]) >= 8 for n in more.names)
    assert len(load_views(tmp_path / "views")) == 8 + len(more.names)


def test_cli_capture_headless_prints_coverage_bars(tmp_path, capsys):
    (tmp_path / "rig.toml").write_text(BOARD_RIG)
    assert (
        main(
            [
                "calibrate",
                "capture",
                str(tmp_path / "v"),
                "--headless",
                "--max-frames",
                "4",
                "--seed",
                "2",
                "--config",
                str(tmp_path / "rig.toml"),
            ]
        )
        == 0
    )
    captured = capsys.readouterr()
    assert "X [" in captured.out and "skew [" in captured.out
    assert "not enough views yet" in captured.out
    assert len(list((tmp_path / "v").glob("*_left.png"))) >= 1


def test_preview_window_shows_corners_and_coverage(tmp_path, capsys):
    from vbfe.calib.preview import CapturePreview

    ((left, right),) = render_board_views(
        RIG, SPEC.board(), [_facing_pose(0.0, 0.0, 0.05)], rng=np.random.default_rng(1)
    )
    collector = ViewCollector(SPEC)
    verdict = collector.offer(left, right)
    preview = CapturePreview()
    try:
        preview.update_view(verdict, collector, left)
        shown = preview.image.image  # RGB
        green = (shown[..., 1] > 200) & (shown[..., 0] < 60) & (shown[..., 2] < 60)
        assert green.sum() > 100  # corner marks and coverage bars drawn over the grey render
        assert "kept view 1" in preview.status.text() and "X [" in preview.status.text()
    finally:
        preview.dispose()
    # the CLI opens the same window unless --headless
    (tmp_path / "rig.toml").write_text(BOARD_RIG)
    assert (
        main(
            [
                "calibrate",
                "capture",
                str(tmp_path / "v"),
                "--max-frames",
                "2",
                "--seed",
                "3",
                "--config",
                str(tmp_path / "rig.toml"),
            ]
        )
        == 0
    )
    assert "kept" in capsys.readouterr().out


def test_capture_of_a_simulated_chessboard_calibrates(tmp_path):
    config = board_config(builtin_rig(), seed=6, board="chessboard", board_p_blur=0.0)
    calib = {"target": "chessboard", "capture_views": 8, "capture_max_views": 8}
    config = config.updated({"calib": calib})
    result = commands.capture(config, tmp_path / "views", max_frames=30)
    assert result.enough and len(result.names) == 8
    from vbfe.calib.stereo import calibrate_stereo

    cal = calibrate_stereo(
        load_views(tmp_path / "views"), BoardSpec(target="chessboard")
    ).calibration
    assert abs(cal.B / true_rig(config).baseline_m - 1) < 0.02
