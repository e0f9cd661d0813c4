"""Simulated device clocks and transport."""

import numpy as np
import pytest

from vbfe.drivers.sim.clocks import DeviceClock, Transport


def test_device_clock_has_offset_and_drift():
    clock = DeviceClock(offset_ns=5_000_000_000, drift_ppm=50.0, tick_ns=1000)
    true = np.arange(0, 100_000_000_000, 1_000_000_000, dtype=np.int64)  # 100 s
    device = clock.device_ns(true)
    slope, intercept = np.polyfit(true / 1e9, device / 1e9, 1)
    assert abs((slope - 1) * 1e6 - 50.0) < 0.01
    assert abs(intercept - 5.0) < 1e-5
    assert np.all(device % 1000 == 0)
    assert np.all(np.abs(clock.true_ns(device) - true) <= 1000)


def test_transport_latency_jitter_and_order():
    transport = Transport(latency_ns=8_000_000, jitter_ns=200_000, rng=np.random.default_rng(1))
    true = np.arange(0, 2_000_000_000, 1_000_000, dtype=np.int64)
    host = np.concatenate([transport.host_ns(true[:1000]), transport.host_ns(true[1000:])])
    delay = host - true
    assert np.all(np.diff(host) >= 0)
    assert abs(np.median(delay) - 8_000_000) < 30_000
    assert 100_000 < delay.std() < 300_000
    assert delay.min() >= 8_000_000 - 600_000


def test_transport_refuses_latency_below_jitter():
    with pytest.raises(ValueError, match="latency"):
        Transport(latency_ns=100, jitter_ns=1000, rng=np.random.default_rng(0))
