"""The V4L2 stereo camera driver against a fake capture with the cv2.VideoCapture surface."""

from __future__ import annotations

import numpy as np
import pytest

from tests.fakes.camera import DISPARITY_PX, FakeStereoCamera, FakeStereoCapture, frame_seq
from vbfe.common.errors import DeviceError
from vbfe.drivers.camera.opencv import OpenCVStereoCamera

W, H, FPS = 32, 24, 30.0


def camera_on(
    *captures: FakeStereoCapture, device: str = "fake-sbs", **kwargs
) -> OpenCVStereoCamera:
    it = iter(captures)
    if len(captures) == 1:
        return OpenCVStereoCamera(
            device=device,
            width=W,
            height=H,
            fps=FPS,
            capture_factory=lambda dev: next(it),
            **kwargs,
        )
    return OpenCVStereoCamera(
        devices=["fake-left", "fake-right"],
        width=W,
        height=H,
        fps=FPS,
        capture_factory=lambda dev: next(it),
        **kwargs,
    )


def read_all(camera: OpenCVStereoCamera, timeout_s: float = 0.3) -> list:
    frames = []
    while (frame := camera.read(timeout_s)) is not None:
        frames.append(frame)
    return frames


def test_side_by_side_split_timestamps_and_injected_drops_counted_exactly():
    drops = (5, 20, 21, 22, 40)
    capture = FakeStereoCapture(W, H, FPS, n_frames=60, drop_seqs=drops, realtime=False)
    with camera_on(capture) as camera:
        frames = read_all(camera)
    assert len(frames) == 60 - len(drops)
    assert camera.stats.dropped == len(drops)
    assert camera.stats.gaps == [(4, 6), (19, 23), (39, 41)]
    assert camera.stats.received == len(frames)
    period_ns = 1e9 / FPS
    for frame in frames:
        assert frame.left.shape == frame.right.shape == (H, W, 3)
        assert frame_seq(frame.left) == frame_seq(frame.right) == frame.seq
        assert abs(frame.t_device_ns - frames[0].t_device_ns - frame.seq * period_ns) <= 1
        # the right eye sees the bar DISPARITY_PX to the left
        assert np.array_equal(frame.left[1:, DISPARITY_PX:], frame.right[1:, :-DISPARITY_PX])
    assert [f.seq for f in frames] == [s for s in range(60) if s not in drops]
    assert all(b.t_host_ns >= a.t_host_ns for a, b in zip(frames, frames[1:], strict=False))


def test_disconnect_gives_device_error_naming_the_device():
    capture = FakeStereoCapture(W, H, FPS, disconnect_after=10, realtime=False)
    with camera_on(capture, device="fake-endoscope-7") as camera:
        frames = [camera.read(1.0) for _ in range(10)]
        assert all(f is not None for f in frames)
        with pytest.raises(DeviceError, match="fake-endoscope-7.*vanished"):
            camera.read(1.0)
        with pytest.raises(DeviceError, match="fake-endoscope-7"):
            camera.read(1.0)  # stays failed


def test_vanished_device_node_is_detected_even_if_capture_claims_open():
    capture = FakeStereoCapture(W, H, FPS, n_frames=0, realtime=False)
    with camera_on(capture, device="/dev/video-vbfe-gone") as camera:
        with pytest.raises(DeviceError, match="/dev/video-vbfe-gone vanished"):
            camera.read(1.0)


def test_two_devices_stay_paired_when_one_eye_drops_a_frame():
    left = FakeStereoCapture(W, H, FPS, n_frames=30, realtime=False, eye="left")
    right = FakeStereoCapture(W, H, FPS, n_frames=30, realtime=False, eye="right", drop_seqs=(7,))
    with camera_on(left, right) as camera:
        frames = read_all(camera)
    assert [frame_seq(f.left) for f in frames] == [frame_seq(f.right) for f in frames]
    assert 7 not in [f.seq for f in frames] and len(frames) == 29
    assert camera.stats.dropped == 1 and camera.describe()["layout"] == "two-devices"


def test_unsupported_mode_and_unopenable_device_are_device_errors():
    capture = FakeStereoCapture(W, H, FPS, realtime=False)
    with pytest.raises(DeviceError, match=r"fake-sbs gives 64x24, not the requested 80x24"):
        OpenCVStereoCamera(
            device="fake-sbs", width=40, height=H, capture_factory=lambda d: capture
        ).open()
    closed = FakeStereoCapture(W, H, FPS)
    closed.release()
    with pytest.raises(DeviceError, match="cannot open camera fake-sbs"):
        camera_on(closed).open()
    with pytest.raises(DeviceError, match="either device"):
        OpenCVStereoCamera(width=W, height=H)


def test_fake_stereo_camera_runs_in_real_time_with_moving_content():
    offset_ns = 5_000_000
    with FakeStereoCamera(
        width=W, height=H, fps=100.0, n_frames=15, clock_offset_ns=offset_ns
    ) as camera:
        frames = read_all(camera, timeout_s=0.3)
    assert [f.seq for f in frames] == list(range(15)) and camera.stats.dropped == 0
    assert not np.array_equal(frames[0].left[1:], frames[5].left[1:])  # the bar moved
    span_ns = frames[-1].t_host_ns - frames[0].t_host_ns
    assert 0.10e9 < span_ns < 0.5e9  # 14 periods of 10 ms, paced on the host clock
    # device time = host time at capture + the offset; the host stamps on receipt, later by
    # a latency that a busy machine stretches for some frames but not for every one
    skew = np.array([f.t_device_ns - f.t_host_ns for f in frames])
    assert np.all(skew <= offset_ns + 1e5) and offset_ns - 5e6 < skew.max()
