"""The CAN trocar driver against a fake TRF85D on python-can's virtual bus."""

from __future__ import annotations

import itertools
import logging
import time

import can
import numpy as np
import pytest

from tests.fakes.trocar import FakeTrocar
from vbfe.common.errors import DeviceError
from vbfe.drivers.registry import open_rig
from vbfe.drivers.trocar.can_trocar import CanTrocar
from vbfe.drivers.trocar.dbc import checksum, default_dbc_path, load_frame_format
from vbfe.rig_config import builtin_rig

_channels = itertools.count()


def _channel() -> str:
    return f"vbfe-test-trocar-{next(_channels)}"


def ramp_profile(t_s: float) -> np.ndarray:
    """0 → 3 N along z over 1 s with small lateral wobble (sign changes included)."""
    return np.array([0.2 * np.sin(7 * t_s), -0.15 * np.cos(5 * t_s), 3.0 * min(t_s, 1.0)])


def read_n(trocar: CanTrocar, n: int) -> list:
    samples = []
    while len(samples) < n:
        sample = trocar.read(timeout_s=2.0)
        assert sample is not None, f"timed out after {len(samples)} samples"
        samples.append(sample)
    return samples


def test_frame_format_round_trips_at_dbc_resolution():
    fmt = load_frame_format()
    assert fmt.resolution_n == pytest.approx(0.001)
    force = np.array([1.2344, -0.0004, -4.9996])
    data = fmt.encode(force, counter=261)
    assert data[7] == checksum(data[:7])
    frame = fmt.decode(data)
    assert frame.counter == 261 % 256
    np.testing.assert_allclose(frame.force_n, force, atol=fmt.resolution_n / 2 + 1e-12)


def test_1000_frames_with_5_percent_corrupt_all_decoded_or_counted(caplog):
    fake = FakeTrocar(
        _channel(), ramp_profile, rate_hz=2000.0, noise_n=0.05, corrupt_fraction=0.05, seed=3
    )
    with fake.trocar() as trocar, caplog.at_level(logging.WARNING):
        with fake:
            samples = read_n(trocar, 1100)
        # drain what was sent before the fake stopped
        while (sample := trocar.read(timeout_s=0.2)) is not None:
            samples.append(sample)
    assert fake.error is None
    assert fake.n_corrupt > 20  # 5 % of ≥1150 frames: the faults really happened
    assert trocar.stats.malformed == fake.n_corrupt
    assert trocar.stats.received == len(samples) == len(fake.sent_forces_n)
    assert trocar.stats.dropped == 0 and trocar.stats.gaps == []
    resolution = trocar.format.resolution_n
    first = samples[0]
    for sample in samples:
        np.testing.assert_allclose(
            sample.force_n, fake.sent_forces_n[sample.seq], atol=resolution / 2 + 1e-9
        )
        # device time = the sender's timestamp (n / 2 kHz on its clock); float epoch seconds
        # carry ~0.2 µs rounding
        assert (
            abs(sample.t_device_ns - first.t_device_ns - (sample.seq - first.seq) * 500_000)
            <= 1_000
        )
    seqs = [s.seq for s in samples]
    assert seqs == sorted(fake.sent_forces_n)  # counter unwrapped across its 256 wrap
    assert seqs[-1] > 1000
    assert "malformed frame" in caplog.text and "vbfe-test-trocar" in caplog.text


def test_counter_gaps_are_counted_as_dropped_and_tare_zeroes():
    dropped = (5, 300, 301, 302, 700)
    fake = FakeTrocar(
        _channel(), lambda t: np.array([0.5, -0.25, 1.0]), rate_hz=2000.0, drop_counters=dropped
    )
    with fake.trocar() as trocar, fake:
        offset = trocar.tare(n_samples=50)
        samples = read_n(trocar, 800)
    np.testing.assert_allclose(offset, [0.5, -0.25, 1.0], atol=0.001)
    assert np.abs(samples[-1].force_n).max() < 0.002
    assert trocar.stats.dropped == len(dropped)
    assert trocar.stats.gaps == [(4, 6), (299, 303), (699, 701)]
    assert trocar.describe()["offset_n"] == pytest.approx([0.5, -0.25, 1.0], abs=0.001)


def test_gap_longer_than_a_counter_wrap_is_counted_from_arrival_times():
    lost = tuple(range(50, 650))  # 600 samples: the 8-bit counter wraps twice in between
    fake = FakeTrocar(_channel(), ramp_profile, rate_hz=2000.0, drop_counters=lost)
    with fake.trocar() as trocar, fake:
        samples = read_n(trocar, 100)
    assert trocar.stats.dropped == 600 and trocar.stats.gaps == [(49, 650)]
    assert [s.seq for s in samples] == list(range(50)) + list(range(650, 700))


def test_unknown_ids_and_wrong_dlc_never_stop_acquisition():
    channel = _channel()
    fmt = load_frame_format()
    with (
        CanTrocar(interface="virtual", channel=channel) as trocar,
        can.Bus(interface="virtual", channel=channel) as sender,
    ):
        sender.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
        sender.send(
            can.Message(arbitration_id=fmt.frame_id, data=b"\x00" * 5, is_extended_id=False)
        )
        sender.send(
            can.Message(
                arbitration_id=fmt.frame_id,
                is_extended_id=False,
                data=fmt.encode(np.array([0.0, 0.0, 2.5]), counter=9),
            )
        )
        sample = trocar.read(timeout_s=1.0)
        assert trocar.read(timeout_s=0.05) is None
    assert sample is not None and sample.seq == 9
    np.testing.assert_allclose(sample.force_n, [0.0, 0.0, 2.5])
    assert trocar.stats.malformed == 1 and trocar.stats.received == 1


def test_bus_off_gives_device_error_naming_channel():
    fake = FakeTrocar(_channel(), ramp_profile, rate_hz=2000.0, disconnect_after=40)
    with fake.trocar() as trocar, fake:
        with pytest.raises(DeviceError, match="bus-off") as info:
            read_n(trocar, 100)
    assert fake.channel in str(info.value) and "bus-off" in str(info.value)


def test_closed_bus_gives_device_error_naming_channel():
    channel = _channel()
    bus = can.Bus(interface="virtual", channel=channel)
    trocar = CanTrocar(interface="virtual", channel=channel, bus=bus)
    trocar.open()
    bus.shutdown()
    with pytest.raises(DeviceError, match=channel):
        trocar.read(timeout_s=0.1)


def test_missing_interface_is_a_device_error_with_bring_up_hint():
    with pytest.raises(DeviceError, match="vbfe-no-such-can.*ip link set"):
        CanTrocar(interface="socketcan", channel="vbfe-no-such-can").open()


def test_own_dbc_without_the_message_or_signals_is_a_clear_error(tmp_path):
    own = tmp_path / "own.dbc"
    own.write_text(default_dbc_path().read_text().replace("TRF85D_Force", "MyForce"))
    with pytest.raises(DeviceError, match=r"own\.dbc has no message 'TRF85D_Force'.*MyForce"):
        CanTrocar(interface="virtual", channel=_channel(), dbc=own)
    with pytest.raises(DeviceError, match=r"lacks signal\(s\) \['Tz'\]"):
        CanTrocar(
            interface="virtual",
            channel=_channel(),
            dbc=own,
            message="MyForce",
            force_signals=("Fx", "Fy", "Tz"),
        )
    with pytest.raises(DeviceError, match="does not exist"):
        CanTrocar(interface="virtual", channel=_channel(), dbc=tmp_path / "none.dbc")
    trocar = CanTrocar(interface="virtual", channel=_channel(), dbc=own, message="MyForce")
    assert trocar.describe()["message"] == "MyForce"


def test_rig_config_with_own_dbc_lacking_counter_and_checksum(tmp_path):
    own = tmp_path / "plain.dbc"
    text = default_dbc_path().read_text().replace("TRF85D_Force", "Plain")
    own.write_text(
        "\n".join(
            line for line in text.splitlines() if "Counter" not in line and "Checksum" not in line
        )
    )
    channel = _channel()
    trocar = open_rig(
        builtin_rig(
            {
                "trocar": {
                    "backend": "can",
                    "interface": "virtual",
                    "channel": channel,
                    "dbc": str(own),
                    "message": "Plain",
                    "counter_signal": "",
                    "checksum_signal": "",
                    "rate_hz": 500.0,
                }
            }
        ),
        families=("trocar",),
    ).trocar
    plain = load_frame_format(own, "Plain", counter_signal=None, checksum_signal=None)
    with trocar, can.Bus(interface="virtual", channel=channel) as sender:
        sent_from_ns = time.time_ns()
        for fz in (1.0, 2.0, 3.0):
            sender.send(
                can.Message(
                    arbitration_id=plain.frame_id,
                    is_extended_id=False,
                    data=plain.encode(np.array([0.0, 0.0, fz])),
                )
            )
        samples = read_n(trocar, 3)
    assert [s.force_n[2] for s in samples] == pytest.approx([1.0, 2.0, 3.0])
    assert [s.seq for s in samples] == [0, 1, 2]
    # the virtual interface stamps each message with the sender's time.time() at send
    stamps = [s.t_device_ns for s in samples]
    assert sent_from_ns - 1_000 <= stamps[0] <= stamps[1] <= stamps[2] <= time.time_ns() + 1_000
    assert "sender's time.time()" in trocar.describe()["device_clock"]
