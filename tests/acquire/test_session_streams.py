"""Extra streams and event marks in the session file: written, read back, inspected, recovered."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vbfe.acquire import (
    SessionError,
    SessionReader,
    SessionWriter,
    finalize_session,
    recover_session,
)
from vbfe.acquire.recording.session_sink import Mark
from vbfe.acquire.session.extra_streams import MARKS, lsl_stream_spec, marks_stream
from vbfe.acquire.session.inspect import inspect_session
from vbfe.drivers.samples import StereoFrame
from vbfe.drivers.streams.records import StreamInfo, StreamSample

ROBOT = StreamInfo(
    name="robot",
    lsl_name="KUKA",
    type="RobotState",
    source_id="kuka-1",
    hostname="ctrl",
    channels=("j1", "j2"),
    units=("rad", "rad"),
    nominal_rate_hz=1000.0,
    markers=False,
    info_xml="<info/>",
)
MARKS_INFO = StreamInfo(
    name="script",
    lsl_name="Psychopy",
    type="Markers",
    source_id="ps",
    hostname="stim",
    channels=("marker",),
    units=("",),
    nominal_rate_hz=0.0,
    markers=True,
)


def _samples(values: np.ndarray, t_ns: np.ndarray, correction_ns: int = 5000) -> list:
    return [
        StreamSample(
            values=v, text=None, seq=k, t_device_ns=int(t) - correction_ns, t_host_ns=int(t)
        )
        for k, (v, t) in enumerate(zip(values, t_ns, strict=False))
    ]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = tmp_path_factory.mktemp("streams") / "s.h5"
    t0 = 10**12
    writer = SessionWriter(
        path,
        (32, 16),
        extra_streams=[lsl_stream_spec(ROBOT), lsl_stream_spec(MARKS_INFO), marks_stream()],
    )
    image = np.zeros((16, 32, 3), np.uint8)
    writer.append_frames(
        [StereoFrame(image, image, k, t0 + k * 10**8, t0 + k * 10**8) for k in range(11)]
    )  # 10 Hz for 1 s
    t_robot = t0 + np.arange(0, 1001) * 10**6  # 1 kHz over the same second
    joints = np.stack([np.arange(1001) * 1e-3, -np.arange(1001) * 1e-3], axis=1)
    writer.append("robot", _samples(joints, t_robot))
    writer.append(
        "script", [StreamSample(None, "trial 1", 0, t0 + 2 * 10**8 - 5000, t0 + 2 * 10**8)]
    )
    writer.append(MARKS, [Mark("grasp ✓", 0, t0 + 3 * 10**8, t0 + 3 * 10**8)])
    writer.add_gap("robot", "queue full", 499, 500, t0 + 5 * 10**8, 0)
    writer.close()
    at_end = {"robot": {"time_corrections": [[t0, 5000], [t0 + 500_000_000, 5000]]}}
    finalize_session(
        path, {"end_reason": "duration reached", "devices_at_end_json": json.dumps(at_end)}
    )
    return path, t0


def test_streams_and_events_read_back(session) -> None:
    path, t0 = session
    with SessionReader(path) as reader:
        assert reader.stream_names() == ["robot", "script"]
        robot = reader.stream("robot")
        assert robot.channels == ["j1", "j2"] and robot.units == ["rad", "rad"]
        assert len(robot) == 1001 and list(robot.seq[:3]) == [0, 1, 2] and robot.seq[-1] == 1000
        assert robot.values.shape == (1001, 2)
        assert np.all(robot.t_host_ns - robot.t_device_ns == 5000)
        assert robot.corrections.tolist() == [[t0, 5000], [t0 + 500_000_000, 5000]]
        assert robot.attrs["lsl_name"] == "KUKA" and robot.attrs["info_xml"] == "<info/>"
        assert reader.clock_fit("robot").offset_ns == 5000
        at_frames = reader.at_frames("robot")
        assert at_frames.shape == (11, 2)
        frame_t = reader.frame_times_ns()
        np.testing.assert_allclose(at_frames[:, 0], (frame_t - t0) / 1e9, atol=1e-9)
        assert reader.events() == [
            {"t_host_ns": t0 + 2 * 10**8, "source": "script", "text": "trial 1"},
            {"t_host_ns": t0 + 3 * 10**8, "source": "mark", "text": "grasp ✓"},
        ]
        assert reader.gaps()[0]["stream"] == "robot"
        with pytest.raises(SessionError, match="holds event markers"):
            reader.at_frames("script")
        with pytest.raises(SessionError, match="has no stream 'arm'; it has robot, script"):
            reader.stream("arm")
    text = inspect_session(path).text()
    assert "stream    robot: 1001 samples at 1000.0 Hz (nominal 1000)" in text
    assert "channels j1 [rad], j2 [rad]" in text and "time correction +0.005 ms" in text
    assert "script: 1 markers" in text and "mark: grasp ✓" in text


def test_recovered_copy_keeps_the_streams(session, tmp_path) -> None:
    path, _ = session
    out, dropped = recover_session(path, tmp_path / "copy.h5")
    assert dropped["robot"] == 0 and dropped["script"] == 0
    with SessionReader(out) as reader:
        assert len(reader.stream("robot")) == 1001 and len(reader.events()) == 2


def test_view_plots_numeric_streams_under_the_force(session, tmp_path) -> None:
    import cv2

    from tests.acquire.test_acquire_view import _has_colour
    from vbfe.acquire.viewer import STREAM_PENS, ReplayViewer, grab_png

    path, _ = session
    with SessionReader(path) as reader:
        window = ReplayViewer(reader)
        window.show()
        assert len(window.stream_plots) == 1  # robot; the marker stream is not plotted
        plot = window.stream_plots[0]
        assert plot.geometry().top() >= window.plot.geometry().bottom()
        image = cv2.imread(str(grab_png(window, tmp_path / "view.png")))
        geo = plot.geometry()
        region = image[geo.top() : geo.bottom(), geo.left() : geo.right()]
        assert _has_colour(region, STREAM_PENS[0]) and _has_colour(region, STREAM_PENS[1])
        window.dispose()


def test_a_robot_stream_checks_the_clocks_at_the_force_corners(session, tmp_path) -> None:
    from vbfe.acquire.sync.streams import stream_offset
    from vbfe.drivers.samples import ForceSample

    rng = np.random.default_rng(0)
    t0, onset_s, lag_s = 10**12, 2.0, 0.004
    t = np.arange(4000) / 1000  # 4 s at 1 kHz: rest, then a pull from 2 s
    force = np.clip(t - onset_s, 0, None) + rng.normal(0, 0.002, len(t))
    joint = 0.05 * np.clip(t - onset_s - lag_s, 0, None) + rng.normal(0, 1e-5, len(t))
    t_ns = t0 + np.round(t * 1e9).astype(np.int64)
    path = tmp_path / "pull.h5"
    writer = SessionWriter(path, (32, 16), extra_streams=[lsl_stream_spec(ROBOT)])
    writer.append_forces(
        [
            ForceSample(np.array([0.0, 0.0, f]), k, int(tk), int(tk))
            for k, (f, tk) in enumerate(zip(force, t_ns, strict=False))
        ]
    )
    writer.append("robot", _samples(np.stack([joint, np.zeros_like(joint)], axis=1), t_ns, 0))
    writer.close()
    with SessionReader(path) as reader:
        estimate = stream_offset(reader, "robot")
    with SessionReader(session[0]) as reader, pytest.raises(SessionError, match="no motion"):
        stream_offset(reader, "script")
    assert estimate.ci95_s[0] <= lag_s <= estimate.ci95_s[1]
    assert abs(estimate.offset_s - lag_s) < 0.002 and estimate.std_s < 0.002
