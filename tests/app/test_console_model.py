"""What the console's model adds to the library, without Qt: the Latest listener, Rig.probe,
the running session number, the capture's coverage map and the Station's recordings."""

import subprocess
import sys
import textwrap

import cv2
import numpy as np
import pytest

from tests import paths
from vbfe.acquire import Acquisition, SessionReader
from vbfe.acquire.recording.latest import Latest
from vbfe.acquire.recording.remote import first_free_run, session_path
from vbfe.calib.board import BoardDetector, BoardSpec
from vbfe.calib.capture import CaptureOptions, ViewCollector
from vbfe.common.errors import SessionError
from vbfe.drivers.registry import open_rig
from vbfe.drivers.rig import RigOptions
from vbfe.rig_config import RigConfig, builtin_rig

SAMPLE = paths.DATA / "opencv_stereo"
SMALL_BENCH = {"width": 160, "height": 90, "fps": 30.0}


def small_config() -> RigConfig:
    return builtin_rig({"bench": dict(SMALL_BENCH)})


def test_latest_keeps_the_newest_frame_the_last_seconds_and_the_rates():
    latest = Latest(window_s=0.5)
    acquisition = Acquisition(open_rig(small_config(), RigOptions(realtime=True)))
    acquisition.add(latest)
    stats = acquisition.run(1.5)
    force = latest.records("force")
    assert latest.frame is not None and latest.frame.left.shape == (90, 160, 3)
    span_s = (force[-1].t_host_ns - force[0].t_host_ns) / 1e9
    assert 0.45 <= span_s <= 0.5  # the window, not the whole run
    view = latest.view("force")
    assert view.count == stats.samples
    assert view.rate_hz == pytest.approx(1000.0, rel=0.05)  # the bench's trocar rate
    # the rate of the frames that came: a bench camera rendering in real time on a loaded
    # machine skips frames itself (device-side, counted apart)
    delivered = stats.frames / (stats.frames + stats.dropped["camera"])
    assert latest.view("camera").rate_hz == pytest.approx(30.0 * delivered, rel=0.2)
    newest = force[-1]
    assert view.clock_offset_s == (newest.t_host_ns - newest.t_device_ns) / 1e9
    assert latest.view("projector").clock_offset_s is None  # the sim projector has no clock


def test_probe_names_the_device_that_does_not_open_with_the_cli_reason():
    config = small_config().updated({"camera": {"backend": "opencv", "device": "/dev/video99"}})
    rig = open_rig(config)
    problems = rig.probe()
    assert problems["trocar"] is None and problems["projector"] is None
    assert problems["camera"].startswith("cannot open camera /dev/video99")
    assert "\n" not in problems["camera"]
    assert not any(d.is_open for d in rig.devices.values())


def test_first_free_run_skips_taken_runs_and_refuses_a_fixed_name_that_exists(tmp_path):
    options = {"root": str(tmp_path), "template": "%p_run-%n.h5", "participant": "P1"}
    assert session_path(first_free_run(options)) == tmp_path / "P1_run-001.h5"
    (tmp_path / "P1_run-001.h5").write_bytes(b"taken")
    (tmp_path / "P1_run-002.h5").write_bytes(b"taken")
    assert session_path(first_free_run(options)) == tmp_path / "P1_run-003.h5"
    fixed = {"root": str(tmp_path), "template": "P1_run-001.h5"}
    with pytest.raises(SessionError, match="already exists"):
        first_free_run(fixed)


def test_coverage_map_counts_the_kept_corners_where_they_lie():
    spec = BoardSpec(squares_x=10, squares_y=7, square_m=0.001, target="chessboard")
    collector = ViewCollector(spec, CaptureOptions(min_pose_distance=0.0, min_sharpness=0.0))
    for k in (1, 2, 3):
        left = cv2.imread(str(SAMPLE / f"left{k:02d}.jpg"))
        right = cv2.imread(str(SAMPLE / f"right{k:02d}.jpg"))
        assert collector.offer(left, right).kept
    grid = collector.coverage_map((640, 480), cells=(4, 3))
    detector = BoardDetector(spec)
    corners = np.concatenate(
        [detector.detect(cv2.imread(str(SAMPLE / f"left{k:02d}.jpg"))).corners for k in (1, 2, 3)]
    )
    expected, _, _ = np.histogram2d(
        corners[:, 1], corners[:, 0], bins=(3, 4), range=((0, 480), (0, 640))
    )
    assert grid.shape == (3, 4) and grid.sum() == 3 * 54
    np.testing.assert_array_equal(grid, expected)


def test_the_station_records_marks_and_stops_without_qt(tmp_path):
    """The model runs in a process that never imports Qt."""
    session = tmp_path / "s.h5"
    script = textwrap.dedent(
        f"""
        import sys, time
        from pathlib import Path
        from vbfe.console.station import SessionRequest, Station
        from vbfe.rig_config import RigConfig, builtin_rig
        station = Station(builtin_rig({{"bench": {SMALL_BENCH!r}}}))
        station.submit(station.go_live).result()
        station.submit(station.start_recording, SessionRequest(Path({str(session)!r}),
                       operator="op", notes="n", conditions={{"k": 2.0}})).result()
        while (station.stats() is None or station.stats().frames < 10):
            time.sleep(0.05)
        station.mark("first")
        station.mark("second")
        finished = station.submit(station.stop_recording).result()
        station.shutdown()
        print(finished.line())
        assert not any(m.split(".")[0] in ("PySide6", "pyqtgraph") for m in sys.modules)
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert "2 marks" in result.stdout
    with SessionReader(session) as reader:
        assert reader.complete
        assert [e["text"] for e in reader.events()] == ["first", "second"]
        assert reader.metadata["operator"] == "op"
        assert reader.metadata["conditions"]["k"] == 2.0
        assert reader.n_frames >= 10


def test_a_settle_the_view_asked_for_mid_restart_leaves_the_new_acquisition_alone(tmp_path):
    """The view polls ``ended()`` from its own thread: it may see the old acquisition's thread
    gone while the worker is between stopping it and starting the next (Stop, then the live
    view restarting). The settle it then submits runs after that, and must not end the new
    live view or the new recording."""
    from vbfe.console.station import SessionRequest, Station

    station = Station(small_config())
    try:
        station.submit(station.go_live).result()
        assert station.submit(station.settle).result() is None  # nothing ended: a no-op
        assert station.acquisition is not None and station.acquisition.running()
        session = tmp_path / "s.h5"
        station.submit(station.start_recording, SessionRequest(session)).result()
        assert station.submit(station.settle).result() is None
        assert station.recording == session and station.acquisition.running()
        finished = station.submit(station.stop_recording).result()
        assert finished.stats.end_reason == "stopped by operator"
    finally:
        station.shutdown()
    with SessionReader(session) as reader:
        assert reader.complete and reader.attrs["end_reason"] == "stopped by operator"
