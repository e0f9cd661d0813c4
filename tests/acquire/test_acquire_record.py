"""Recording sessions from devices and reading them back through SessionReader."""

from __future__ import annotations

import time

import h5py
import numpy as np
import pytest

import vbfe.acquire.recording.session_sink as sink_module
from tests.acquire.test_acquire_devices import bar_devices, bar_image, force_profile
from vbfe.acquire import Recorder, SessionError, SessionReader, store_calibration

CAM_OFFSET_NS = 5_000_000_000


def record(path, duration_s=1.0, compression="lzf", **options):
    devices = bar_devices(**options)
    with Recorder(
        devices,
        path,
        compression=compression,
        flush_interval_s=0.2,
        metadata={"operator": "ana", "notes": "bench 3"},
        min_free_bytes=0,
        pattern=np.zeros((48, 64, 3), np.uint8),
        pattern_name="debruijn",
    ) as rec:
        stats = rec.run(duration_s)
    return devices, stats


@pytest.mark.parametrize("compression", ["gzip", "none", "zstd", "lzf", "blosc-lz4", "mjpeg"])
def test_round_trip_keeps_frames_forces_events_and_metadata(tmp_path, compression):
    path = tmp_path / "s.h5"
    devices, stats = record(path, compression=compression)
    with SessionReader(path) as s:
        assert s.complete and s.n_frames == stats.frames >= 30
        assert s.metadata["operator"] == "ana" and s.metadata["compression"] == compression
        assert s.metadata["devices"]["camera"]["kind"] == "BarCamera"
        seqs = s.stream_times("camera")[2]
        np.testing.assert_array_equal(seqs, np.arange(s.n_frames))
        for i in (0, s.n_frames // 2, s.n_frames - 1):
            frame = s.frame(i)
            expected = bar_image(64 / 4 + 8 * force_profile(i / 30.0)[2], 64, 48)
            if compression == "mjpeg":
                assert np.abs(frame.left.astype(int) - expected).mean() < 3
            else:
                assert frame.left[0, 0, 0] == i % 256
                np.testing.assert_array_equal(frame.left[1:], expected[1:])
            assert frame.t_device_ns == CAM_OFFSET_NS + round(i / 30.0 * 1e9)
        forces, (t_dev, _, _) = s.forces_n(), s.stream_times("force")
        assert len(forces) == stats.samples >= 150
        truth = force_profile((t_dev + 3_000_000_000) / 1e9)
        assert np.abs(forces - truth).max() < 0.03  # noise is 5 mN
        assert [e.pattern for e in s.projector_events()] == ["debruijn"]
        assert s.force_axes == ["x", "y", "z"]


def test_force_at_frames_is_the_force_at_each_frame_time(tmp_path):
    path = tmp_path / "s.h5"
    record(
        path,
        duration_s=2.0,
        force_latency_s=0.004,
        force_jitter_s=0.002,
        latency_s=0.03,
        jitter_s=0.003,
    )
    with SessionReader(path) as s:
        f = s.force_at_frames()
        assert f.shape == (s.n_frames, 3)
        ok = ~np.isnan(f[:, 2])
        assert ok.sum() >= s.n_frames - 2
        # frames arrive 26 ms later than forces of the same instant (longer transport latency),
        # which the clock fit cannot know: frame i is paired with the force at i/30 s + 26 ms
        truth = force_profile(np.arange(s.n_frames) / 30.0 + 0.026)
        assert np.abs(f[ok] - truth[ok]).max() < 0.03
        frame_step = np.diff(s.frame_times_ns())
        assert np.abs(frame_step - 1e9 / 30).max() < 0.3e6  # jitter removed by the clock fit
        t_f, t_c = s.force_times_ns()[0], s.frame_times_ns()[0]
        assert abs((t_c - t_f) / 1e6 - 26.0) < 1.5


def test_clock_fit_recovers_offset_and_drift(tmp_path):
    path = tmp_path / "s.h5"
    record(
        path,
        duration_s=10.0,
        speed=40.0,
        drift_ppm=80.0,
        jitter_s=0.001,
        force_drift_ppm=-40.0,
        force_jitter_s=0.001,
    )
    with SessionReader(path) as s:
        cam, force = s.clock_fit("camera"), s.clock_fit("force")
        assert cam.drift_ppm == pytest.approx(80.0, abs=10)
        assert force.drift_ppm == pytest.approx(-40.0, abs=10)
        assert cam.jitter_ns == pytest.approx(0.001e9, rel=0.5)
        assert cam.drift_uncertainty_ppm < 10


def test_camera_that_vanishes_ends_the_session_cleanly_with_a_marked_gap(tmp_path):
    path = tmp_path / "s.h5"
    _, stats = record(path, duration_s=10.0, disconnect_after=20)
    assert "camera disconnected" in stats.end_reason
    with SessionReader(path) as s:
        assert s.complete and s.n_frames == 20
        gaps = [g for g in s.gaps() if g["reason"] == "device disconnected"]
        assert gaps == [
            dict(
                stream="camera",
                reason="device disconnected",
                last_seq=19,
                next_seq=-1,
                t_host_ns=gaps[0]["t_host_ns"],
                count=0,
            )
        ]
        assert "camera disconnected" in s.attrs["end_reason"]


def test_trocar_that_vanishes_ends_the_session_cleanly(tmp_path):
    path = tmp_path / "s.h5"
    _, stats = record(path, duration_s=10.0, force_disconnect_after=100)
    assert "force disconnected" in stats.end_reason
    with SessionReader(path) as s:
        assert len(s.forces_n()) == 100
        assert [g["stream"] for g in s.gaps()] == ["force"]


def test_full_queue_counts_drops_and_marks_gaps(tmp_path):
    path = tmp_path / "s.h5"
    devices = bar_devices(speed=None, force_speed=4.0, n_frames=400, width=320, height=240)
    rec = Recorder(devices, path, compression="lzf", queue_size=1, min_free_bytes=0)
    rec.start()
    deadline = time.monotonic() + 20
    while devices.camera._seq < 400 and time.monotonic() < deadline:
        time.sleep(0.01)
    stats = rec.stop()
    with SessionReader(path) as s:
        queue_drops = s.attrs["camera_queue_dropped"]
        assert queue_drops == stats.dropped["camera"] > 0
        assert s.n_frames + queue_drops == 400
        gaps = [g for g in s.gaps() if g["reason"] == "queue full" and g["stream"] == "camera"]
        assert sum(g["count"] for g in gaps) == queue_drops
        seqs = s.stream_times("camera")[2]
        for g in gaps:
            if g["next_seq"] == -1:  # a burst at the very end
                assert g["last_seq"] == seqs[-1]
                continue
            assert g["next_seq"] - g["last_seq"] - 1 == g["count"]
            assert g["next_seq"] in seqs and g["last_seq"] in seqs


def test_unwritable_or_missing_destination_is_refused_by_name(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with open(locked / "probe", "w"):
            writable_as_root = True
    except PermissionError:
        writable_as_root = False
    if not writable_as_root:
        with pytest.raises(SessionError, match="locked.*not writable"):
            Recorder(bar_devices(), locked / "s.h5")
    with pytest.raises(SessionError, match="nowhere.*does not exist"):
        Recorder(bar_devices(), tmp_path / "nowhere" / "s.h5")
    with pytest.raises(SessionError, match="GB free"):
        Recorder(bar_devices(), tmp_path / "s.h5", min_free_bytes=1 << 62)
    (tmp_path / "old.h5").write_bytes(b"x")
    with pytest.raises(SessionError, match="old.h5 already exists"):
        Recorder(bar_devices(), tmp_path / "old.h5")


def test_readonly_file_system_is_reported_by_name(tmp_path):
    with pytest.raises(SessionError, match="/proc"):
        Recorder(bar_devices(), "/proc/s.h5", min_free_bytes=0)


def test_disk_filling_up_stops_and_finalizes_between_flushes(tmp_path, monkeypatch):
    path = tmp_path / "s.h5"
    devices = bar_devices()
    rec = Recorder(devices, path, flush_interval_s=10.0, min_free_bytes=1000)
    start = time.monotonic()
    monkeypatch.setattr(
        sink_module, "free_bytes", lambda d: 10 if time.monotonic() - start > 1.0 else 10**9
    )
    rec.start()
    with pytest.raises(SessionError, match=f"disk almost full.*{tmp_path}.*finalized with"):
        rec.run(5.0)
    assert time.monotonic() - start < 3.0  # watched continuously, not at the next flush (10 s)
    with SessionReader(path) as s:
        assert s.complete and s.n_frames > 0
        assert s.attrs["end_reason"].startswith("disk almost full")


def test_not_a_session_truncated_or_missing_files_raise_session_error(tmp_path):
    plain = tmp_path / "plain.h5"
    with h5py.File(plain, "w") as f:
        f["x"] = [1, 2]
    with pytest.raises(SessionError, match="plain.h5 is an HDF5 file but not a vbfe session"):
        SessionReader(plain)
    good = tmp_path / "good.h5"
    record(good, duration_s=0.5)
    cut = tmp_path / "cut.h5"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 3])
    with pytest.raises(SessionError, match="cut.h5"):
        with SessionReader(cut) as s:
            [s.frame(i) for i in range(s.n_frames)]
            s.forces_n()
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all" * 100)
    with pytest.raises(SessionError, match="junk.h5 is not a readable HDF5 file"):
        SessionReader(junk)
    with pytest.raises(SessionError, match="missing.h5 does not exist"):
        SessionReader(tmp_path / "missing.h5")


def test_store_calibration_adds_and_replaces_the_yaml(tmp_path):
    path = tmp_path / "s.h5"
    record(path, duration_s=0.3)
    with SessionReader(path) as s:
        assert s.calibration_yaml() is None
    store_calibration(path, "%YAML:1.0\nK1: 1\n")
    store_calibration(path, "%YAML:1.0\nK1: 2\n")
    with SessionReader(path) as s:
        assert s.calibration_yaml() == "%YAML:1.0\nK1: 2\n"


def test_a_camera_that_is_not_real_time_waits_for_the_writer_instead_of_dropping(tmp_path):
    path = tmp_path / "s.h5"
    devices = bar_devices(speed=None, force_speed=4.0, n_frames=400, width=320, height=240)
    described = devices.camera.describe()
    devices.camera.describe = lambda: {**described, "realtime": False}
    rec = Recorder(devices, path, compression="lzf", queue_size=1, min_free_bytes=0)
    rec.start()
    deadline = time.monotonic() + 60
    while rec.update_stats().frames < 400 and time.monotonic() < deadline:
        time.sleep(0.05)
    stats = rec.stop()
    assert stats.dropped["camera"] == 0
    with SessionReader(path) as s:
        assert s.attrs["camera_queue_dropped"] == 0 and s.n_frames == 400
        np.testing.assert_array_equal(s.stream_times("camera")[2], np.arange(400))
        assert [g for g in s.gaps() if g["stream"] == "camera"] == []


def test_frames_stored_while_behind_read_back_unchanged_through_hdf5s_own_filter(tmp_path):
    from vbfe.acquire import SessionWriter
    from vbfe.drivers.samples import StereoFrame

    rng = np.random.default_rng(0)
    frames = [
        StereoFrame(
            *(rng.normal(120, 3, (48, 64, 3)).clip(0, 255).astype(np.uint8) for _ in range(2)),
            t_device_ns=k,
            t_host_ns=k,
            seq=k,
        )
        for k in range(4)
    ]
    writer = SessionWriter(tmp_path / "s.h5", (64, 48), "gzip")
    for k, frame in enumerate(frames):
        writer.append("camera", [frame], behind=k % 2 == 0)  # even frames: the writer behind
    writer.close()
    assert writer.frames_stored == 2
    with h5py.File(tmp_path / "s.h5") as f:  # HDF5's deflate and Fletcher-32, not vbfe's code
        left = f["camera/left"]
        sizes = [left.id.get_chunk_info(k).size for k in range(4)]
        for k, frame in enumerate(frames):
            np.testing.assert_array_equal(left[k], frame.left)
            np.testing.assert_array_equal(f["camera/right"][k], frame.right)
    stored, compressed = sizes[0::2], sizes[1::2]
    assert min(stored) > frames[0].left.nbytes > 1.5 * max(compressed)
