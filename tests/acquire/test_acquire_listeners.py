"""Listeners of an acquisition: a new one attaches to a recording in a few lines; one rig
opens with rollback; a failing listener stops the acquisition without losing the session."""

from __future__ import annotations

import time
from dataclasses import dataclass

import h5py
import numpy as np
import pytest

from tests.acquire.test_acquire_devices import ProfileForce, RecordingProjector, bar_devices
from tests.fakes.camera import FakeStereoCamera
from vbfe.acquire import (
    Acquisition,
    Listener,
    Recorder,
    SessionError,
    SessionReader,
    SessionWriter,
    recover_session,
)
from vbfe.acquire.session.layout import marker_stream, vector_stream
from vbfe.common.errors import DeviceError
from vbfe.drivers.device import SampleStream
from vbfe.drivers.pacing import sleep_until
from vbfe.drivers.registry import open_rig
from vbfe.drivers.rig import Rig, RigOptions
from vbfe.rig_config import builtin_rig


class FrameCounter(Listener):
    """The whole of a new listener: count the frames of a recording."""

    def __init__(self) -> None:
        self.frames = 0

    def on_frames(self, frames) -> None:
        self.frames += len(frames)


def test_a_frame_counting_listener_sees_every_recorded_frame(tmp_path):
    counter = FrameCounter()
    with Recorder(
        bar_devices(speed=8.0), tmp_path / "s.h5", min_free_bytes=0, listeners=(counter,)
    ) as recorder:
        stats = recorder.run(2.0)
    with SessionReader(tmp_path / "s.h5") as session:
        assert counter.frames == session.n_frames == stats.frames >= 55


class Broken(Listener):
    def on_samples(self, samples) -> None:
        raise ValueError("a bug in a listener")


def test_a_failing_listener_stops_the_acquisition_and_the_session_is_finalized(tmp_path):
    recorder = Recorder(
        bar_devices(speed=8.0), tmp_path / "s.h5", min_free_bytes=0, listeners=(Broken(),)
    )
    with pytest.raises(ValueError, match="a bug in a listener"):
        recorder.run(5.0)
    assert not any(d.is_open for d in recorder.rig.devices.values())
    assert recorder.rig.truth is None  # no simulated backend: no truth
    with SessionReader(tmp_path / "s.h5") as session:
        assert session.complete and session.n_frames < 5 * 30


def test_a_simulated_rig_is_an_ordinary_rig_with_truth_and_options():
    config = builtin_rig({"bench": dict(width=160, height=90, fps=20.0)})
    rig = open_rig(config, RigOptions(seed=3, realtime=False))
    described = rig.describe()
    assert described["bench"]["seed"] == 3 and described["conditions"]["seed"] == 3
    assert set(described["devices"]) == {"camera", "trocar", "projector"}
    assert rig.truth is not None
    counter = FrameCounter()
    acquisition = Acquisition(rig, listeners=(counter,))
    stats = acquisition.run(0.5)
    assert counter.frames == stats.frames == 10


def test_a_device_failing_to_open_closes_those_already_opened():
    rig = bar_devices()
    rig.trocar._open = lambda: (_ for _ in ()).throw(DeviceError("trocar unplugged"))
    with pytest.raises(DeviceError, match="unplugged"):
        with rig:
            pass
    assert not rig.camera.is_open


@dataclass(frozen=True)
class Kinematics:
    values: np.ndarray
    seq: int
    t_device_ns: int
    t_host_ns: int


class FakeRobot(SampleStream[Kinematics]):
    """A device of a further kind: 7 joint angles at 100 Hz, read into the stream "robot"."""

    stream = "robot"

    def _open(self) -> None:
        self._t0, self._n = time.monotonic_ns(), 0

    def _close(self) -> None:
        pass

    def _read_sample(self, timeout_s: float) -> Kinematics | None:
        due = self._t0 + self._n * 10_000_000
        if not sleep_until(due, timeout_s):
            return None
        self._n += 1
        return Kinematics(np.full(7, self._n, float), self._n - 1, due, time.monotonic_ns())

    def describe(self) -> dict[str, object]:
        return {"kind": "FakeRobot"}


def test_a_further_device_kind_is_recorded_as_an_extra_stream_and_read_back(tmp_path):
    rig = bar_devices(speed=8.0)
    rig.devices["robot"] = FakeRobot()
    with pytest.raises(SessionError, match=r"\['robot'\] have no session stream"):
        Recorder(rig, tmp_path / "no-spec.h5", min_free_bytes=0).run(1.0)
    assert not rig.camera.is_open
    spec = vector_stream("robot", [f"q{i}" for i in range(7)], units="rad")
    with Recorder(rig, tmp_path / "s.h5", min_free_bytes=0, streams=(spec,)) as recorder:
        recorder.run(1.0)
    with SessionReader(tmp_path / "s.h5") as session:
        values = session.stream_column("robot", "values")
        t_dev, t_host, seq = session.stream_times("robot")
        assert values.shape == (len(seq), 7) and len(seq) >= 30
        assert np.array_equal(values[:, 0], seq + 1)
        assert session.clock_fit("robot") is not None


@dataclass(frozen=True)
class Marker:
    text: str
    seq: int
    t_device_ns: int
    t_host_ns: int


def test_a_marker_stream_keeps_its_text_and_gaps_through_a_recovery_copy(tmp_path):
    writer = SessionWriter(tmp_path / "s.h5", (8, 6), extra_streams=[marker_stream("markers")])
    writer.append("markers", [Marker("start", 0, 5, 10), Marker("stop ü", 1, 6, 11)])
    writer.add_gap("markers", "queue full", 1, 3, 12, 1)
    writer.close()
    out, dropped = recover_session(tmp_path / "s.h5", tmp_path / "r.h5")
    with SessionReader(out) as session:
        assert list(session.stream_column("markers", "text")) == ["start", "stop ü"]
        assert session.stream_times("markers")[1].tolist() == [10, 11]
        assert session.gaps()[0]["stream"] == "markers" and dropped["markers"] == 0


class SlowView(Listener):
    """A view that takes 0.2 s over each frame, as the live estimate may on a busy machine."""

    lossy = True

    def __init__(self) -> None:
        self.seen: list[int] = []

    def on_frames(self, frames) -> None:
        time.sleep(0.2)
        self.seen.extend(frame.seq for frame in frames)


def endoscope_rig() -> Rig:
    """The real OpenCV driver on a fake 30 fps endoscope whose kernel buffers never overflow
    (a reader starved on a loaded machine gets every frame late, none lost), the bar trocar."""
    return Rig(FakeStereoCamera(n_buffers=1 << 20), ProfileForce(speed=1.0), RecordingProjector())


def test_a_slow_lossy_listener_skips_frames_counted_and_the_file_loses_none(tmp_path):
    view = SlowView()  # a sixth of the camera's rate, on a thread apart from the writer's
    with Recorder(
        endoscope_rig(),
        tmp_path / "s.h5",
        min_free_bytes=0,
        listeners=(view,),
    ) as recorder:
        stats = recorder.run(1.5)
    with SessionReader(tmp_path / "s.h5") as session:
        assert session.n_frames == stats.frames >= 10
        np.testing.assert_array_equal(session.stream_times("camera")[2], np.arange(stats.frames))
        assert session.attrs["camera_queue_dropped"] == 0 and not session.gaps()
    assert len(view.seen) <= 9 and stats.live_skipped >= stats.frames - 9
    assert view.seen == sorted(view.seen)  # the newest frame each time, never an older one
    # every frame written was seen or counted as skipped by the view; beyond them only those
    # the camera's reader read past the end (neither the file nor the view keeps them)
    end_ns = stats.first_frame_host_ns + 1.5e9
    past_end = (stats.newest_read_host_ns - end_ns) * 30 / 1e9 + 1
    assert stats.frames <= len(view.seen) + stats.live_skipped <= stats.frames + past_end


class Stall(Listener):
    """A listener of every frame that holds the writer's thread once for half a second."""

    def __init__(self) -> None:
        self.frames = 0
        self.at = 0  # the frames handed over before the stall

    def on_frames(self, frames) -> None:
        self.frames += len(frames)
        if self.frames >= 5 and not self.at:  # frames come in batches on a busy machine
            self.at = self.frames
            time.sleep(0.5)


def test_a_writer_behind_stores_frames_uncompressed_until_it_has_caught_up(tmp_path):
    with Recorder(
        endoscope_rig(),
        tmp_path / "s.h5",
        compression="gzip",
        min_free_bytes=0,
        queue_size=8,  # fewer than the stall's 15 frames: the queue holds what fits in
        queue_bytes=48 * 6 * 64 * 48,  # 48 frames, of which the stall fills more than an eighth
        listeners=(stall := Stall(),),
    ) as recorder:
        stats = recorder.run(1.5)
    with SessionReader(tmp_path / "s.h5") as session:
        np.testing.assert_array_equal(session.stream_times("camera")[2], np.arange(stats.frames))
        assert session.attrs["camera_queue_dropped"] == 0
        assert 10 <= session.attrs["camera_frames_stored"] < stats.frames
        assert any("stored uncompressed" in line for line in session.log())
    with h5py.File(tmp_path / "s.h5") as f:  # caught up: the last frames compressed again
        left = f["camera/left"]
        raw = left[0].nbytes
        sizes = [left.id.get_chunk_info(k).size for k in range(stats.frames)]
        assert min(sizes[stall.at : stall.at + 10]) > raw > sizes[-1]
