"""Which clock the trocar's device time is on, and what the clock fit makes of it.

Real python-can buses: the virtual interface (with and without device timestamps) and, where
the kernel has vcan, socketcan on a vcan interface.
"""

from __future__ import annotations

import itertools
import shutil
import socket
import subprocess
import time

import can
import numpy as np
import pytest

from tests.acquire.test_acquire_devices import BarCamera, RecordingProjector
from vbfe.acquire import Recorder, SessionReader
from vbfe.acquire.session.clock import fit_clock
from vbfe.drivers.rig import Rig
from vbfe.drivers.trocar.can_clock import HOST_CLOCK
from vbfe.drivers.trocar.can_trocar import CAN_ERR_CRTL, CanTrocar
from vbfe.drivers.trocar.dbc import load_frame_format

FORMAT = load_frame_format()
RATE_HZ = 500.0
_channels = itertools.count()


class SteppedHost:
    """A host clock the test sets to each message's true arrival time before it is read."""

    def __init__(self) -> None:
        self.now_ns = 0

    def __call__(self) -> int:
        return self.now_ns


def force_message(n: int, timestamp: float = 0.0) -> can.Message:
    data = FORMAT.encode(np.array([0.0, 0.1, 1.0 + 1e-3 * (n % 100)]), counter=n)
    return can.Message(
        arbitration_id=FORMAT.frame_id, data=data, is_extended_id=False, timestamp=timestamp
    )


def run_stream(
    device_stamps: bool,
    n: int = 3000,
    offset_s: float = 1234.5,
    drift_ppm: float = 80.0,
    seed: int = 0,
):
    """Send ``n`` frames over the virtual bus; the sensor's clock runs ``drift_ppm`` fast and
    ``offset_s`` ahead of the host; the host reads each 0.2-1.2 ms after it was sent."""
    rng = np.random.default_rng(seed)
    channel = f"vbfe-clock-{next(_channels)}"
    host = SteppedHost()
    trocar = CanTrocar(interface="virtual", channel=channel, rate_hz=RATE_HZ, host_clock=host)
    true_s = np.arange(n) / RATE_HZ
    latency_s = rng.uniform(0.2e-3, 1.2e-3, n)
    samples = []
    with trocar, can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as bus:
        for k in range(n):
            stamp = offset_s + true_s[k] * (1 + drift_ppm * 1e-6) if device_stamps else 0.0
            bus.send(force_message(k, stamp))
            host.now_ns = round((100.0 + true_s[k] + latency_s[k]) * 1e9)
            samples.append(trocar.read(timeout_s=1.0))
        facts = trocar.describe()
    return samples, facts, true_s, latency_s, offset_s, drift_ppm


def test_device_timestamps_are_the_device_clock_and_the_fit_recovers_offset_and_drift():
    samples, facts, true_s, latency_s, offset_s, drift_ppm = run_stream(device_stamps=True)
    assert "sender's time.time()" in facts["device_clock"]
    t_dev = np.array([s.t_device_ns for s in samples])
    t_host = np.array([s.t_host_ns for s in samples])
    expected = np.round((offset_s + true_s * (1 + drift_ppm * 1e-6)) * 1e9)
    assert np.abs(t_dev - expected).max() <= 1_000  # the message's own stamp (float s)
    fit = fit_clock(t_dev, t_host)
    assert fit.drift_ppm == pytest.approx(drift_ppm, abs=3.0)
    # host time of a sample with zero latency: 100 s + true time
    zero_latency_host = fit.to_host(t_dev) - np.round(np.median(latency_s) * 1e9)
    assert np.abs(zero_latency_host - np.round((100.0 + true_s) * 1e9)).max() < 0.3e6
    assert fit.offset_ns == pytest.approx(
        (100.0 - offset_s + np.median(latency_s)) * 1e9, abs=0.3e6
    )


def test_without_device_timestamps_the_host_receive_time_is_used():
    samples, facts, *_ = run_stream(device_stamps=False, n=200)
    assert facts["device_clock"] == HOST_CLOCK
    assert all(s.t_device_ns == s.t_host_ns for s in samples)
    fit = fit_clock(
        np.array([s.t_device_ns for s in samples]), np.array([s.t_host_ns for s in samples])
    )
    assert fit.drift_ppm == pytest.approx(0.0, abs=1e-6) and abs(fit.offset_ns) <= 1


def test_error_frames_and_bus_state_changes_are_counted_and_marked():
    channel = f"vbfe-clock-{next(_channels)}"
    with (
        CanTrocar(interface="virtual", channel=channel) as trocar,
        can.Bus(interface="virtual", channel=channel) as bus,
    ):
        bus.send(force_message(0))
        bus.send(can.Message(arbitration_id=0x02, is_error_frame=True, data=bytes(8)))  # lost arb
        bus.send(
            can.Message(
                arbitration_id=CAN_ERR_CRTL,
                is_error_frame=True,
                data=bytes([0, 0x10, 0, 0, 0, 0, 0, 0]),
            )
        )  # error passive
        bus.send(force_message(1))
        got = [trocar.read(1.0), trocar.read(1.0)]
    assert [s.seq for s in got] == [0, 1] and trocar.stats.errors == 2
    marks = trocar.stats.take_marks()
    assert [(m.reason, m.last_seq, m.count) for m in marks] == [
        ("device error", 0, 1),
        ("bus state change", 0, 1),
    ]
    assert trocar.stats.dropped == 0 and trocar.stats.take_marks() == []


def _vcan() -> str | None:
    """Why socketcan on vcan cannot run here, or None when a vcan interface is up."""
    if not hasattr(socket, "AF_CAN"):
        return "this Python has no AF_CAN sockets"
    if shutil.which("ip") is None:
        return "no 'ip' command (iproute2) to create vcan0"
    up = subprocess.run(["ip", "link", "show", "vcan0"], capture_output=True, text=True)
    if up.returncode == 0:
        return None
    made = subprocess.run(
        ["ip", "link", "add", "dev", "vcan0", "type", "vcan"], capture_output=True, text=True
    )
    if made.returncode != 0:
        return (
            f"'ip link add dev vcan0 type vcan' failed ({made.stderr.strip()}): the kernel "
            "has no vcan module here or we may not add interfaces"
        )
    subprocess.run(["ip", "link", "set", "vcan0", "up"], check=False)
    return None


@pytest.mark.skipif(bool(reason := _vcan()), reason=str(reason))
def test_trocar_over_socketcan_on_vcan0_uses_kernel_receive_time():
    with (
        CanTrocar(interface="socketcan", channel="vcan0") as trocar,
        can.Bus(interface="socketcan", channel="vcan0") as bus,
    ):
        before = time.time_ns()
        for k in range(20):
            bus.send(force_message(k))
        samples = [trocar.read(1.0) for _ in range(20)]
    assert [s.seq for s in samples] == list(range(20))
    assert "kernel receive time" in trocar.describe()["device_clock"]
    assert before <= samples[0].t_device_ns <= samples[-1].t_device_ns <= time.time_ns()


def test_recorded_session_stores_bus_errors_as_force_gaps(tmp_path):
    channel = f"vbfe-clock-{next(_channels)}"
    devices = Rig(
        BarCamera(disconnect_after=20),
        CanTrocar(interface="virtual", channel=channel),
        RecordingProjector(),
    )
    rec = Recorder(devices, tmp_path / "s.h5", min_free_bytes=0)
    rec.start()
    with can.Bus(interface="virtual", channel=channel) as bus:
        for k in range(5):
            bus.send(force_message(k))
        bus.send(can.Message(arbitration_id=0x08, is_error_frame=True, data=bytes(8)))
        bus.send(
            can.Message(
                arbitration_id=CAN_ERR_CRTL,
                is_error_frame=True,
                data=bytes([0, 0x04, 0, 0, 0, 0, 0, 0]),
            )
        )  # rx error warning
        for k in range(5, 10):
            bus.send(force_message(k))
        stats = rec.run(10.0)
    assert stats.end_reason.startswith("camera disconnected")
    with SessionReader(tmp_path / "s.h5") as session:
        force_gaps = [
            (g["reason"], g["last_seq"], g["count"])
            for g in session.gaps()
            if g["stream"] == "force"
        ]
        assert force_gaps == [("device error", 4, 1), ("bus state change", 4, 1)]
        assert list(session.stream_times("force")[2]) == list(range(10))
        assert session.attrs["force_device_errors"] == 2
