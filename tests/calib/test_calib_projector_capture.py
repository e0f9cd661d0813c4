"""`calibrate capture` and `calibrate projector-capture` run the same code on the simulated bench
(through the camera/projector driver interfaces, chosen by the rig config) and on real drivers
(the V4L2 driver on the fake endoscope, the serial projector on a pty)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests import paths
from tests.fakes.camera import FakeStereoCamera
from tests.fakes.serial_projector import FakeSerialProjector
from vbfe.calib.board import BoardDetector, BoardSpec
from vbfe.calib.projector import load_captures, projector_images
from vbfe.calib.projector_capture import GrayCaptureOptions, capture_gray_code
from vbfe.common.errors import CalibrationError
from vbfe.drivers.projector.serial_projector import SerialProjector, default_commands_path

REPO = paths.REPO


def vbfe(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "MPLBACKEND": "Agg"}
    return subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_cli_capture_and_gray_code_capture_on_the_bench_board_scene(tmp_path):
    """Both commands with the sim backend; the bench is chosen only in the rig config."""
    (tmp_path / "rig.toml").write_text(
        '[bench]\nscene = "board"\nfps = 10.0\nboard_hold_s = 10.0\nboard_in_projector = true\n'
        "board_max_tilt_deg = 45.0\nprojector_latency_ms = 0.0\nexposure_ms = 0.0\n"
        "[calib]\nprojector_settle_s = 0.0\n"
    )
    (tmp_path / "hand.toml").write_text('[bench]\nscene = "board"\n')
    done = vbfe(
        "calibrate",
        "capture",
        "views",
        "--headless",
        "--max-frames",
        "6",
        "--seed",
        "2",
        "--config",
        "hand.toml",
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    kept = sorted((tmp_path / "views").glob("*_left.png"))
    assert 1 <= len(kept) <= 6 and "X [" in done.stdout
    detector = BoardDetector(BoardSpec())
    assert all(len(detector.detect(cv2.imread(str(p)))) >= 12 for p in kept)

    done = vbfe(
        "calibrate",
        "projector-capture",
        "gray",
        "--poses",
        "2",
        "--config",
        "rig.toml",
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert "wrote 2 poses" in done.stdout
    captures = load_captures(tmp_path / "gray")
    assert len(captures) == 2
    white, black, patterns = projector_images((1024, 768))  # the bench projector
    assert all(len(c.patterns) == len(patterns) == 40 for c in captures)
    for c in captures:  # the board is lit by what the projector showed
        lit = c.white.astype(int) - c.black.astype(int)
        assert np.median(lit) > 60
        coarse = c.patterns[0].astype(int) - c.black  # the coarsest stripe: half the field lit
        assert 0.2 < np.mean(coarse > lit / 2) < 0.8
    assert json.loads((tmp_path / "gray" / "projector.json").read_text()) == {"size": [1024, 768]}
    # the two poses differ: the board moved between them
    assert np.abs(captures[0].white.astype(int) - captures[1].white).mean() > 6

    # a second run adds poses after the first ones; a different projector size is refused
    (tmp_path / "gray" / "projector.json").write_text('{"size": [800, 600]}')
    done = vbfe(
        "calibrate",
        "projector-capture",
        "gray",
        "--poses",
        "1",
        "--config",
        "rig.toml",
        cwd=tmp_path,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == (
        "vbfe calibrate: error: gray holds captures for a 800x600 projector but this one is "
        "1024x768; use a new folder"
    )
    assert len(load_captures(tmp_path / "gray")) == 2


def _gray_code_table(tmp_path: Path, n_patterns: int) -> Path:
    """The shipped serial command table with stored patterns white, black, gray_NN."""
    text = default_commands_path().read_text()
    text = (
        text[: text.rindex("[patterns]")]
        + "[patterns]\nwhite = 0\nblack = 1\n"
        + "".join(f"gray_{k:02d} = {k + 2}\n" for k in range(n_patterns))
    )
    path = tmp_path / "gray.toml"
    path.write_text(text)
    return path


def test_gray_code_capture_on_the_fake_endoscope_and_serial_projector(tmp_path):
    size = (1024, 768)
    n_gray = len(projector_images(size)[2])
    table = _gray_code_table(tmp_path, n_gray)
    # the fake scene never rests (a moving bar), so any frame counts as still and new
    options = GrayCaptureOptions(settle_s=0.05, still_level=1e9, change_level=0.0, still_frames=1)
    with FakeSerialProjector(n_patterns=n_gray + 2) as fake:
        with (
            FakeStereoCamera(width=64, height=48, fps=60.0) as camera,
            SerialProjector(
                port=fake.port, commands=table, width=size[0], height=size[1]
            ) as projector,
        ):
            written = capture_gray_code(camera, projector, tmp_path / "gray", 2, options)
    assert [p.name for p in written] == ["pose_000", "pose_001"]
    shown = [line for line in fake.received if line.startswith("PATTERN")]
    one_pose = (
        ["PATTERN 0"]
        + ["PATTERN 0", "PATTERN 1"]
        + [f"PATTERN {k + 2}" for k in range(n_gray)]
        + ["PATTERN 0"]
    )  # wait, sequence, check
    assert shown == one_pose * 2
    captures = load_captures(tmp_path / "gray")
    assert [c.white.shape for c in captures] == [(48, 64)] * 2
    assert all(len(c.patterns) == n_gray for c in captures)
    for pose in written:
        frames = json.loads((pose / "frames.json").read_text())
        assert [f["pattern"] for f in frames] == ["white", "black"] + [
            f"gray_{k:02d}" for k in range(n_gray)
        ] + ["white"]
        for f in frames:  # each kept frame arrived after the projector acknowledged + settle
            assert f["frame_t_host_ns"] - f["shown_t_host_ns"] >= 0.05e9
        seqs = [f["frame_seq"] for f in frames]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)


def test_a_board_that_never_moves_to_a_new_pose_stops_the_capture_keeping_what_was_done(tmp_path):
    # the first pose needs no movement; the second waits for a change that never comes
    options = GrayCaptureOptions(
        settle_s=0.0, still_level=1e9, change_level=1e9, still_frames=1, pose_timeout_s=0.3
    )
    table = _gray_code_table(tmp_path, 40)
    with FakeSerialProjector(n_patterns=42) as fake:
        with (
            FakeStereoCamera(width=64, height=48, fps=60.0) as camera,
            SerialProjector(port=fake.port, commands=table, width=1024, height=768) as projector,
        ):
            with pytest.raises(
                CalibrationError,
                match="did not come to rest at a new pose within "
                "0.3 s.*poses captured so far are kept",
            ):
                capture_gray_code(camera, projector, tmp_path / "gray", 2, options)
    assert [p.name for p in (tmp_path / "gray").glob("pose_*")] == ["pose_000"]
    assert len(load_captures(tmp_path / "gray")[0].patterns) == 40
