"""The device base classes: open/close guards and the template ``read`` around one hook."""

from __future__ import annotations

import time

import numpy as np
import pytest

from vbfe.common.errors import DeviceError
from vbfe.drivers.samples import ForceSample
from vbfe.drivers.trocar.base import ForceSensor


class ScriptedSensor(ForceSensor):
    """Replays a script: a sequence number, ``None`` (nothing yet), ``"bad"`` (a malformed
    frame) or ``"gone"`` (the device vanished)."""

    rate_hz = 100.0

    def __init__(self, script: list) -> None:
        super().__init__()
        self.script, self.opened, self.closed, self.hook_calls = list(script), 0, 0, 0

    def _open(self) -> None:
        self.opened += 1

    def _close(self) -> None:
        self.closed += 1

    def _read_sample(self, timeout_s: float) -> ForceSample | None:
        self.hook_calls += 1
        step = self.script.pop(0) if self.script else None
        if step is None:
            time.sleep(min(timeout_s, 0.01))
            return None
        if step == "bad":
            self.stats.malformed += 1
            return None
        if step == "gone":
            raise DeviceError("scripted sensor unplugged")
        return ForceSample(np.array([1.0, 2.0, 3.0 + step]), step, step, step)


def test_read_before_open_names_the_device_and_open_close_are_idempotent():
    sensor = ScriptedSensor([0])
    with pytest.raises(DeviceError, match="ScriptedSensor is not open; call open"):
        sensor.read()
    sensor.open()
    sensor.open()
    sensor.close()
    sensor.close()
    assert (sensor.opened, sensor.closed) == (1, 1)


def test_gaps_count_lost_samples_less_malformed_ones_and_retries_within_the_deadline():
    with ScriptedSensor([0, 1, None, "bad", 3, 7, None, 8]) as sensor:
        seqs = [sensor.read(1.0).seq for _ in range(4)]
    assert seqs == [0, 1, 3, 7]
    # sample 2 arrived malformed (not lost); 4, 5, 6 never arrived
    assert sensor.stats.dropped == 3 and sensor.stats.gaps == [(3, 7)]
    assert sensor.stats.received == 4 and sensor.stats.malformed == 1


def test_timeout_returns_none_after_the_deadline():
    with ScriptedSensor([]) as sensor:
        start = time.monotonic()
        assert sensor.read(0.1) is None
        assert 0.1 <= time.monotonic() - start < 0.5 and sensor.hook_calls >= 5


def test_a_vanished_device_keeps_failing_until_reopened():
    with ScriptedSensor([0, "gone", 5]) as sensor:
        assert sensor.read().seq == 0
        with pytest.raises(DeviceError, match="unplugged"):
            sensor.read()
        with pytest.raises(DeviceError, match="unplugged"):
            sensor.read()  # sticky: the hook is not asked again
        assert sensor.hook_calls == 2
    sensor.open()
    assert sensor.read().seq == 5 and sensor.stats.dropped == 0  # a fresh sequence


def test_tare_subtracts_the_mean_of_raw_samples():
    with ScriptedSensor(list(range(10))) as sensor:
        offset = sensor.tare(4)
        sample = sensor.read()
    np.testing.assert_allclose(offset, [1.0, 2.0, 4.5])
    np.testing.assert_allclose(sample.force_n, [0.0, 0.0, 3.0 + 4 - 4.5])
    assert sensor.describe()["offset_n"] == pytest.approx([1.0, 2.0, 4.5])
