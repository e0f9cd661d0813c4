"""Extra streams from LSL: the [streams] table, and real outlets read on loopback."""

from __future__ import annotations

import time

import numpy as np
import pylsl
import pytest

from tests.fakes.lsl_outlets import FakeRobot, MarkerOutlet, unique
from vbfe.common.errors import ConfigError, DeviceError
from vbfe.drivers.streams import StreamSource, stream_sources
from vbfe.drivers.streams.lsl import LslStream
from vbfe.drivers.streams.opening import missing_streams, streams_from_config


def _read_all(stream: LslStream, until: float) -> list:
    samples = []
    while time.monotonic() < until:
        sample = stream.read(0.05)
        if sample is not None:
            samples.append(sample)
    return samples


def test_streams_table_is_checked() -> None:
    specs = stream_sources(
        {
            "streams": {
                "robot": {"name": "KUKA", "type": "RobotState"},
                "script": {"type": "Markers", "required": False},
            }
        }
    )
    assert [(s.key, s.predicate(), s.required) for s in specs] == [
        ("robot", "name='KUKA' and type='RobotState'", True),
        ("script", "type='Markers'", False),
    ]
    for table, words in (
        ({"robot": {}}, "names no stream"),
        ({"robot": {"name": "a", "rate": 3}}, "unknown key 'rate'"),
        ({"camera": {"name": "a"}}, "cannot name a session stream"),
        ({"marks": {"name": "a"}}, "cannot name a session stream"),
        ({"Robot": {"name": "a"}}, "cannot name a session stream"),
        ({"robot": {"name": "a'b"}}, "must not contain a quote"),
        ({"robot": {"name": "a", "required": "yes"}}, "true or false"),
        ({"robot": "KUKA"}, "is not a table"),
    ):
        with pytest.raises(ConfigError, match=words):
            stream_sources({"streams": table})


def test_robot_stream_on_the_host_clock_with_metadata() -> None:
    with FakeRobot(unique("robot")) as robot:
        stream = LslStream(StreamSource(key="robot", name=robot.name, resolve_timeout_s=5.0))
        with stream:
            samples = _read_all(stream, time.monotonic() + 0.6)
            time.sleep(0.05)
            info = stream.info
            description = stream.describe()
    assert info.channels == tuple(f"joint{j}_position" for j in range(1, 8))
    assert info.units == ("rad",) * 7 and info.nominal_rate_hz == 1000.0 and not info.markers
    assert description["source_id"] == f"{robot.name}-serial-1"
    t_host = np.array([s.t_host_ns for s in samples])
    values = np.array([s.values for s in samples])
    assert [s.seq for s in samples] == list(range(len(samples)))
    assert len(t_host) >= 400  # ~0.6 s at 1 kHz, minus the connection
    due = robot.due_times_ns()
    index = np.searchsorted(due, t_host)
    # every sample is one the robot pushed, in order, none missing, on the host clock
    assert np.all(np.diff(index) == 1)
    assert np.max(np.abs(t_host - due[index])) <= 1_000_000
    np.testing.assert_allclose(values, robot.value(due[index]))
    assert stream.stats.dropped == 0 and stream.stats.received == len(t_host)
    (_, correction_ns), *_ = description["time_corrections"]
    assert abs(correction_ns) < 1_000_000  # publisher on this host: no offset
    assert all(s.t_host_ns - s.t_device_ns == correction_ns for s in samples[:100])


def test_a_gap_in_the_publishers_stamps_is_its_timing_not_a_loss() -> None:
    name = unique("gappy")
    outlet = pylsl.StreamOutlet(pylsl.StreamInfo(name, "Test", 1, 100.0, pylsl.cf_float32, name))
    with LslStream(StreamSource(key="gappy", name=name)) as stream:
        outlet.wait_for_consumers(5.0)
        now = time.monotonic()
        stamps = [now + i / 100 for i in list(range(10)) + list(range(20, 25))]  # 10 not sent
        outlet.push_chunk([[float(i)] for i in range(15)], stamps)
        samples = _read_all(stream, time.monotonic() + 0.3)
    assert [s.values[0] for s in samples] == list(range(15))  # everything sent arrived
    assert stream.stats.dropped == 0 and stream.stats.gaps == []
    timing = stream.describe()["publisher_timing"]
    assert timing == {"gaps": 1, "missing_periods": 10, "worst_gap_ns": timing["worst_gap_ns"]}
    assert abs(timing["worst_gap_ns"] - 110_000_000) <= 1_000


def test_an_inlet_buffer_overflow_counts_the_samples_lost() -> None:
    """A 500 Hz robot read into a 1 s inlet buffer that is not read for 2.5 s: liblsl drops
    the oldest samples; exactly those are counted lost, and the publisher was regular."""
    with FakeRobot(unique("flood"), rate_hz=500.0, joints=2) as robot:
        source = StreamSource(key="robot", name=robot.name, buffer_s=1.0)
        with LslStream(source) as stream:
            robot.outlet.wait_for_consumers(5.0)
            samples = _read_all(stream, time.monotonic() + 0.5)
            time.sleep(2.5)  # the recorder stalls: the buffer holds 1 s of the 2.5
            samples += _read_all(stream, time.monotonic() + 0.5)
    due = robot.due_times_ns()
    index = np.searchsorted(due, [s.t_device_ns for s in samples])
    assert np.all(due[index] == [s.t_device_ns for s in samples])  # each one the robot sent
    never_received = int(index[-1] - index[0] + 1 - len(index))
    assert never_received >= 600  # ~1.5 s of 500 Hz dropped by liblsl
    assert stream.stats.dropped == never_received and len(stream.stats.gaps) == 1
    assert stream.describe()["publisher_timing"]["gaps"] == 0


def test_markers_arrive_as_text() -> None:
    marks = MarkerOutlet(unique("marks"))
    with LslStream(StreamSource(key="marks", name=marks.name)) as stream:
        marks.outlet.wait_for_consumers(5.0)
        sent = [marks.mark("trial 1 start"), marks.mark("grasp ✓")]
        samples = _read_all(stream, time.monotonic() + 0.3)
    assert stream.info.markers
    assert [s.text for s in samples] == ["trial 1 start", "grasp ✓"]
    t_host = np.array([s.t_host_ns for s in samples])
    assert np.max(np.abs(t_host - np.array(sent))) <= 1_000_000


def test_required_missing_is_refused_optional_is_a_warning() -> None:
    name = unique("absent")
    config = {
        "streams": {
            "robot": {"name": name, "resolve_timeout_s": 0.3},
            "script": {"name": name + "-m", "required": False, "resolve_timeout_s": 0.3},
        }
    }
    streams = streams_from_config(config)
    with pytest.raises(DeviceError, match=f"robot \\(LSL name='{name}'\\) was not found"):
        streams["robot"].open()
    streams["script"].open()  # an optional stream missing: open, not read, one warning
    assert streams["script"].is_open and streams["script"].stream is None
    assert streams["robot"].stream == "robot"
    (warning,) = missing_streams(streams.values())
    assert warning.startswith(f"optional stream script (LSL name='{name}-m') was not found")
    assert warning.endswith("recording without it")
    streams["script"].close()


def test_two_matching_streams_are_ambiguous() -> None:
    name = unique("twin")
    outlets = [
        pylsl.StreamOutlet(pylsl.StreamInfo(name, "Test", 1, 10.0, pylsl.cf_float32, f"{name}-{k}"))
        for k in "ab"
    ]
    time.sleep(0.2)  # both announced before the resolve
    with pytest.raises(DeviceError, match="add its source_id"):
        LslStream(StreamSource(key="twin", name=name, resolve_timeout_s=1.0)).open()
    with LslStream(StreamSource(key="twin", name=name, source_id=f"{name}-b")) as stream:
        assert stream.info.source_id == f"{name}-b"
    del outlets
