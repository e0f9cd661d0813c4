"""The linuxpy V4L2 camera against a fake at linuxpy's device boundary (tests/fakes/v4l2.py)."""

from __future__ import annotations

import json
import time

import cv2
import h5py
import numpy as np
import pytest

from tests.acquire.test_acquire_devices import ProfileForce, RecordingProjector
from tests.fakes.camera import DISPARITY_PX, render_eye
from tests.fakes.v4l2 import FakeV4L2Node, fake_factories
from vbfe.acquire import Recorder
from vbfe.common.errors import DeviceError
from vbfe.drivers.camera.linuxpy_v4l2 import LinuxpyStereoCamera
from vbfe.drivers.rig import Rig
from vbfe.drivers.samples import JpegStereoFrame

W, H = 64, 48
MANUAL = {
    "auto_exposure": 1,
    "exposure_time_absolute": 100,
    "gain": 0,
    "white_balance_automatic": False,
    "white_balance_temperature": 4600,
}


def stereo(left: FakeV4L2Node, right: FakeV4L2Node, **kwargs) -> LinuxpyStereoCamera:
    return LinuxpyStereoCamera(
        devices=[left.path, right.path], width=W, height=H, **fake_factories(left, right), **kwargs
    )


def pair(**kwargs) -> tuple[FakeV4L2Node, FakeV4L2Node]:
    return (
        FakeV4L2Node("/fake/video0", W, H, eye="left", **kwargs),
        FakeV4L2Node("/fake/video2", W, H, eye="right", **kwargs),
    )


def read_until_timeout(camera: LinuxpyStereoCamera) -> list:
    frames = []
    while (frame := camera.read(timeout_s=0.2)) is not None:
        frames.append(frame)
    return frames


def test_drops_are_counted_exactly_from_kernel_sequence_numbers():
    left, right = pair(n_frames=40, drop_seqs={5, 9, 10, 31})
    right.drop_seqs = frozenset({5, 9, 10, 31, 17})  # one more frame lost on the right only
    with stereo(left, right) as camera:
        frames = read_until_timeout(camera)
    seqs = [f.seq for f in frames]
    assert seqs == [s for s in range(40) if s not in {5, 9, 10, 31, 17}]
    assert camera.stats.dropped == 5 and camera.stats.received == 35
    assert camera.stats.gaps == [(4, 6), (8, 11), (16, 18), (30, 32)]
    for frame in frames:  # each pair shows one instant: the same sequence in both eyes
        assert isinstance(frame, JpegStereoFrame)
        assert frame.encoded == (left.delivered[frame.seq], right.delivered[frame.seq])
        # kernel time of the frame (a struct timeval: µs)
        assert (
            abs(frame.t_device_ns - frames[0].t_device_ns - (frame.seq - frames[0].seq) * 1e9 / 30)
            <= 1_000
        )
    decoded = frames[3].left  # decoded only on demand
    assert np.abs(decoded.astype(int) - render_eye(W, H, frames[3].seq)).mean() < 3


def test_buffers_the_driver_flags_as_corrupt_are_malformed_not_dropped():
    left, right = pair(n_frames=12, error_seqs={3})
    with stereo(left, right) as camera:
        frames = read_until_timeout(camera)
    assert [f.seq for f in frames] == [s for s in range(12) if s != 3]
    assert camera.stats.malformed == 2  # both eyes' buffer 3
    assert camera.stats.dropped == 0 and camera.stats.gaps == []


def test_kernel_drops_of_a_late_reader_are_exact():
    start_ns = time.monotonic_ns() + 100_000_000  # both sensors triggered together
    left, right = pair(n_frames=45, realtime=True, start_ns=start_ns)
    camera = stereo(left, right, buffers=2)
    with camera:
        first = camera.read(1.0)
        time.sleep(0.4)  # the reader stalls: 12 frame periods with 2 buffers
        frames = [first] + read_until_timeout(camera)
    lost = set(left.kernel_dropped) | set(right.kernel_dropped)
    assert len(lost) >= 8
    assert camera.stats.dropped == len(lost) == 45 - len(frames)
    assert sorted(set(range(45)) - {f.seq for f in frames}) == sorted(lost)


def test_unsynchronized_eyes_are_paired_by_kernel_time():
    left, right = pair(n_frames=30, realtime=True)  # each eye starts at its own stream-on
    camera = stereo(left, right, buffers=2)
    with camera:
        frames = [camera.read(1.0)]
        time.sleep(0.3)
        frames += read_until_timeout(camera)
    right_seq = {data: seq for seq, data in right.delivered.items()}
    for frame in frames:  # each pair: both images within half a period of each other
        assert frame.t_device_ns == left.times[frame.seq]
        assert abs(frame.t_device_ns - right.times[right_seq[frame.encoded[1]]]) <= 0.5e9 / 30
    returned = frames[-1].seq - frames[0].seq + 1
    assert camera.stats.dropped == returned - len(frames) >= 5


def test_clock_controls_and_format_in_describe():
    left, right = pair(n_frames=3)
    with stereo(left, right, controls=MANUAL) as camera:
        facts = camera.describe()
    assert facts["device_clock"] == "V4L2 buffer timestamp (CLOCK_MONOTONIC, start of exposure)"
    assert facts["controls"]["/fake/video0"] == {**MANUAL, "white_balance_automatic": 0}
    assert left.controls_by_name["exposure_time_absolute"].value == 100
    assert right.controls_by_name["white_balance_temperature"].value == 4600
    assert facts["fourcc"] == "MJPG" and facts["layout"] == "two-devices"


def test_unsupported_control_is_one_line_error_naming_it():
    left, right = pair()
    camera = stereo(left, right, controls={"exposure_absolute": 100})
    with pytest.raises(DeviceError) as err:
        camera.open()
    message = str(err.value)
    assert "'exposure_absolute'" in message and "/fake/video0" in message and "\n" not in message
    assert "exposure_time_absolute" in message  # what it has instead
    assert not camera.is_open and left.closed


def test_control_value_the_device_clips_is_refused():
    left, right = pair()
    camera = stereo(left, right, controls={"auto_exposure": 1, "exposure_time_absolute": 5000})
    with pytest.raises(DeviceError, match="exposure_time_absolute: set 5000, reads back 2047"):
        camera.open()


def test_side_by_side_yuyv_is_converted_and_split():
    node = FakeV4L2Node("/fake/video4", W, H, fourcc="YUYV", eye="both", n_frames=4)
    camera = LinuxpyStereoCamera(
        device=node.path, width=W, height=H, fourcc="YUYV", **fake_factories(node)
    )
    with camera:
        frames = read_until_timeout(camera)
    assert [f.seq for f in frames] == [0, 1, 2, 3] and frames[0].encoded is None
    for frame in frames:
        for eye, shift in ((frame.left, 0), (frame.right, DISPARITY_PX)):
            assert eye.shape == (H, W, 3)
            # 4:2:2 chroma on a grey scene: a few grey levels of rounding at most
            assert np.abs(eye.astype(int) - render_eye(W, H, frame.seq, shift)).max() <= 6


def _recording(tmp_path, left, right, duration_s=None):
    devices = Rig(
        stereo(left, right, controls=MANUAL), ProfileForce(speed=1.0), RecordingProjector()
    )
    rec = Recorder(devices, tmp_path / "s.h5", compression="mjpeg", min_free_bytes=0)
    rec.start()
    return rec.run(duration_s), tmp_path / "s.h5"


def test_recorded_mjpeg_frames_are_the_devices_bytes(tmp_path):
    # a synchronized head: frame k of both eyes is one instant, so the pair holds seq k twice
    left, right = pair(realtime=True, n_frames=200, start_ns=time.monotonic_ns() + 200_000_000)
    stats, path = _recording(tmp_path, left, right, duration_s=0.6)
    assert stats.end_reason == "duration reached" and stats.frames >= 10
    with h5py.File(path, "r") as f:
        seqs = f["camera/seq"][:]
        for eye, node in (("left", left), ("right", right)):
            data, index = f[f"camera/{eye}_jpeg"][:], f[f"camera/{eye}_jpeg_index"][:]
            for seq, (offset, length) in zip(seqs, index, strict=False):
                assert data[offset : offset + length].tobytes() == node.delivered[seq]
        devices = json.loads(f.attrs["metadata_json"])["devices"]
        assert devices["camera"]["controls"]["/fake/video2"]["exposure_time_absolute"] == 100
        image = cv2.imdecode(data[index[0, 0] : index[0].sum()], cv2.IMREAD_COLOR)
        assert image.shape == (H, W, 3)


def test_camera_vanishing_mid_stream_ends_session_with_marked_gap(tmp_path):
    left, right = pair(vanish_after=12)
    stats, path = _recording(tmp_path, left, right)
    assert stats.end_reason.startswith("camera disconnected") and "vanished" in stats.end_reason
    with h5py.File(path, "r") as f:
        assert f.attrs["complete"] and len(f["camera/seq"]) == 12
        gaps = f["gaps"][:]
        reasons = list(f["gaps"].attrs["reasons"])
        camera_gaps = [g for g in gaps if g[0] == 0]
        assert len(camera_gaps) == 1
        assert reasons[camera_gaps[0][1]] == "device disconnected"
        assert camera_gaps[0][2] == 11 and camera_gaps[0][3] == -1
