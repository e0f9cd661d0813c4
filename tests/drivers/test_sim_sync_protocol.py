"""The bench's sync protocol: taps as short force impulses the tissue follows, projector
latency, and frames that integrate the light over their exposure."""

from __future__ import annotations

import numpy as np
import pytest

from vbfe.common.errors import DeviceError
from vbfe.drivers.sim import SimBench
from vbfe.drivers.sim.mechanics import REST, TAP, TapProtocol


def test_taps_are_short_impulses_at_irregular_times_that_the_tissue_follows():
    taps = TapProtocol.random(np.random.default_rng(4), 12, 15.0, stiffness_n_per_m=80.0)
    starts = np.array(taps.tap_times_s)
    assert len(starts) == 12 and starts[0] >= 0.8 and starts[-1] + taps.tap_s <= 15.0 - 0.8
    gaps = np.diff(starts)
    assert gaps.min() >= taps.tap_s + 0.4 and gaps.std() > 0.1  # irregular, never overlapping
    t = np.arange(0.0, 15.0, 0.001)
    u, force, phase = taps.state(t)
    assert np.all(force[phase == REST] == 0) and np.all(force[phase == TAP] > 0)
    first = (t > starts[0]) & (t < starts[0] + taps.tap_s)
    assert force[first].max() == pytest.approx(taps.peaks_n[0], rel=1e-3)
    assert np.allclose(u, force / 80.0)
    with pytest.raises(DeviceError, match="do not fit"):
        TapProtocol.random(np.random.default_rng(0), 40, 10.0)


def test_sync_bench_records_taps_in_force_and_motion():
    bench = SimBench(
        width=320,
        height=180,
        protocol="sync",
        sync_taps=5,
        sync_duration_s=6.0,
        noise_sigma=0.0,
        distortion=False,
    )
    start = bench.trial.protocol.tap_times_s[0]
    with bench.camera() as camera:
        frames = [camera.read() for _ in range(int((start + 0.3) * 30))]
    rest, tap = frames[int(start * 30) - 2].left, frames[int((start + 0.075) * 30)].left
    assert np.abs(rest.astype(int) - frames[0].left).max() == 0  # still between taps
    assert np.abs(tap.astype(int) - rest).mean() > 1.0  # the tap moves the tissue
    assert bench.duration_s() == 6.0 and bench.conditions()["protocol"] == "sync"


def test_a_switch_mid_exposure_lights_a_share_of_the_frame_after_the_projector_latency():
    bench = SimBench(
        width=320,
        height=180,
        fps=30.0,
        scene="plane",
        noise_sigma=0.0,
        ambient=0.1,
        distortion=False,
        exposure_ms=20.0,
        projector_latency_ms=25.0,
        image_jitter_ms=0.0,
    )
    period_s, exposure_s = 1 / 30, 0.020
    black = np.zeros((bench.rig.projector.height, bench.rig.projector.width, 3), np.uint8)
    camera, projector = bench.camera(), bench.projector()
    with camera, projector:
        projector.show(black, "black")
        levels, commands = [], []
        for k in range(60):
            if k in (10, 30, 45):
                commands.append(projector.show(black + 255 * (k != 30), "flash").t_host_ns)
            levels.append(float(camera.read().left.mean()))
    dark, bright = min(levels), max(levels)
    share = (np.array(levels) - dark) / (bright - dark)
    times = np.arange(60) * period_s
    light = np.full(60, 0.0)
    for host_ns, on in zip(commands, (1.0, 0.0, 1.0), strict=False):
        change = (host_ns - bench.host_epoch_ns) / 1e9 + 0.025
        after = np.clip((times + exposure_s / 2 - change) / exposure_s, 0, 1)
        light = np.where(after > 0, light * (1 - after) + on * after, light)
    assert np.abs(share - light)[3:].max() < 0.02  # frames 0-2: before "black" lights the plane
    assert np.any((share > 0.05) & (share < 0.95))  # a partially exposed frame
    assert np.argmax(share > 0.5) > 10  # the light comes after the command


def test_exposure_longer_than_the_frame_period_is_refused():
    with pytest.raises(DeviceError, match="exposure_ms"):
        SimBench(fps=30.0, exposure_ms=40.0)
