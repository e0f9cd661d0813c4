"""The simulated bench as driver backends: time, clocks, force, projection, truth."""

import json
import time

import numpy as np
import pytest

from vbfe.common.errors import ConfigError, DeviceError
from vbfe.drivers.registry import open_rig
from vbfe.drivers.sim import SimBench
from vbfe.rig_config import builtin_rig


def small_bench(**kw) -> SimBench:
    return SimBench(width=320, height=180, **kw)


def read_frames(camera, n):
    return [camera.read(timeout_s=1.0) for _ in range(n)]


def drain(trocar):
    samples = []
    while (sample := trocar.read(timeout_s=0.01)) is not None:
        samples.append(sample)
    return samples


def test_camera_frames_advance_true_time_by_one_period():
    bench = small_bench(fps=30.0, camera_drift_ppm=100.0)
    with bench.camera() as camera:
        frames = read_frames(camera, 5)
    assert [f.seq for f in frames] == list(range(5))
    truth = bench.session_truth(np.array([f.t_device_ns for f in frames]))
    assert np.all(np.diff(truth["frame_t_true_ns"]) == bench.frame_period_ns)
    assert abs(bench.frame_period_ns - 1e9 / 30) < 1
    device_steps = np.diff([f.t_device_ns for f in frames])
    assert np.all(np.abs(device_steps - bench.frame_period_ns * (1 + 100e-6)) <= 1)
    assert frames[0].left.shape == (180, 320, 3) and frames[0].left.dtype == np.uint8
    assert not np.array_equal(frames[0].left, frames[1].left)  # sensor noise at least


def test_trocar_follows_true_force_within_quantization_and_noise():
    bench = small_bench(rest_s=0.0, stiffness_n_per_m=200.0, pull_speed_m_per_s=0.002)
    camera, trocar = bench.camera(), bench.trocar()
    with camera, trocar:
        frames = read_frames(camera, 30)  # one simulated second
        samples = drain(trocar)
    # what has reached the host when the last frame did: 37 ms more than the frame's time
    assert max(s.t_host_ns for s in samples) <= frames[-1].t_host_ns
    assert abs(len(samples) - (29 * bench.frame_period_ns + 37_000_000) / 1e6) < 5
    force = np.array([s.force_n for s in samples])
    true_ns = bench.trocar_clock.true_ns(np.array([s.t_device_ns for s in samples]))
    truth = bench.trial.forces(true_ns / 1e9)
    residual = force - truth
    assert np.abs(residual.mean(axis=0)).max() < 0.01
    assert 0.02 < residual.std() < 0.04  # σ = 0.03 N plus 0.01 N quantization
    assert np.allclose(force * 100, np.round(force * 100), atol=1e-9)
    assert np.linalg.norm(force[-50:].mean(axis=0)) > 0.3  # the pull is under way
    device = np.array([s.t_device_ns for s in samples], np.int64)
    assert np.all(np.abs(np.diff(device) - 1_000_000 * (1 - 60e-6)) <= 1000)  # −60 ppm, 1 µs tick


def test_host_offset_between_streams_is_the_configured_latency_difference():
    bench = small_bench(image_latency_ms=50.0, force_latency_ms=13.0)
    camera, trocar = bench.camera(), bench.trocar()
    with camera, trocar:
        frames = read_frames(camera, 15)
        samples = drain(trocar)
    truth = bench.session_truth(np.array([f.t_device_ns for f in frames]))
    image_delay = (
        np.array([f.t_host_ns for f in frames]) - bench.host_epoch_ns - truth["frame_t_true_ns"]
    )
    force_true = bench.trocar_clock.true_ns(np.array([s.t_device_ns for s in samples]))
    force_delay = np.array([s.t_host_ns for s in samples]) - bench.host_epoch_ns - force_true
    offset_ms = (np.median(image_delay) - np.median(force_delay)) / 1e6
    assert abs(offset_ms - 37.0) < 1.0
    assert np.all(truth["image_minus_force_host_offset_ns"] == 37_000_000)


def test_projector_pattern_is_what_the_camera_sees():
    bench = small_bench(noise_sigma=0.0, ambient=0.1)
    camera, projector = bench.camera(), bench.projector()
    with camera, projector:
        white = np.full((projector.height, projector.width, 3), 255, np.uint8)
        event = projector.show(white, "white")
        bright = camera.read().left.astype(float)
        projector.show(np.zeros_like(white), "black")
        dark = camera.read().left.astype(float)
        with pytest.raises(DeviceError, match="1024x768"):
            projector.show(white[:10], "wrong size")
    assert event.pattern == "white" and event.seq == 0
    assert np.median(dark) < 30 and np.median(bright) > 150


def test_description_rebuilds_the_same_bench():
    bench = small_bench(seed=7, stiffness_n_per_m=40.0, pull_speed_m_per_s=0.01, textured=True)
    description = json.loads(json.dumps(bench.describe()))
    twin = SimBench.from_description(description)
    assert twin.conditions() == bench.conditions()
    with bench.camera() as a, twin.camera() as b:
        fa, fb = read_frames(a, 2), read_frames(b, 2)
    assert np.array_equal(fa[1].left, fb[1].left)
    assert description["trial"]["protocol"]["stiffness_n_per_m"] == 40.0


def test_render_truth_matches_the_rig():
    bench = small_bench()
    with bench.camera() as camera:
        frames = read_frames(camera, 3)
    truth = bench.render_truth(frames[-1].t_device_ns)
    valid = truth["valid_left"]
    assert valid.mean() > 0.99
    f, baseline = bench.rig.left.f, bench.rig.baseline_m
    depth = f * baseline / truth["disparity_left_px"][valid].astype(np.float64)
    assert np.abs(depth / truth["depth_left_m"][valid] - 1).max() < 1e-6


def test_config_builds_the_bench_and_refuses_unknown_keys():
    config = builtin_rig()
    rig = open_rig(config)
    assert isinstance(rig.truth, SimBench)
    assert (rig.camera.width, rig.camera.height) == (
        config.tables["bench"]["width"],
        config.tables["bench"]["height"],
    )
    assert rig.truth.duration_s() > 5.0
    assert rig.describe()["conditions"]["simulated"] is True
    with pytest.raises(ConfigError, match="stifness"):
        SimBench.from_config({"stifness_n_per_m": 40.0})
    with pytest.raises(DeviceError, match="no options"):
        SimBench().camera(device="/dev/video0")


def test_realtime_camera_paces_frames_by_the_host_clock():
    bench = SimBench(width=160, height=90, fps=20.0, realtime=True, image_latency_ms=10.0)
    with bench.camera() as camera:
        start = time.monotonic()
        frames = read_frames(camera, 4)
        elapsed = time.monotonic() - start
    assert all(f is not None for f in frames)
    assert elapsed > 0.15  # frames 0..3 arrive at 10, 60, 110, 160 ms
    host = np.array([f.t_host_ns for f in frames])
    assert np.all(np.abs(host - time.monotonic_ns()) < 2e9)  # host clock is the real one
