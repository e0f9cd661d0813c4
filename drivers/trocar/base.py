"""The force sensor interface every trocar backend implements."""

from __future__ import annotations

import dataclasses

import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.drivers.device import SampleStream
from vbfe.drivers.samples import ForceSample


class ForceSensor(SampleStream[ForceSample]):
    """A force sensor (the TRF85D trocar): open, read timestamped samples, tare, close.

    ``read`` returns ``None`` on timeout, raises :class:`~vbfe.common.errors.DeviceError` when
    the interface is gone (bus-off, unplugged), and never raises for one bad frame: backends
    count it in ``stats.malformed`` and go on. Backends implement ``_open``, ``_close`` and
    ``_read_sample(timeout_s)`` returning the *raw* (untared) sample; ``read`` subtracts
    ``offset_n``.
    """

    stream = "force"  # the session stream an acquisition reads it into
    rate_hz: float
    axes: tuple[str, ...] = ("x", "y", "z")

    def __init__(self) -> None:
        super().__init__()
        self.offset_n = np.zeros(len(self.axes))

    def _finish(self, sample: ForceSample) -> ForceSample:
        if not self.offset_n.any():
            return sample
        return dataclasses.replace(sample, force_n=sample.force_n - self.offset_n)

    def tare(self, n_samples: int = 500, timeout_s: float = 1.0) -> np.ndarray:
        """Make the mean of the next ``n_samples`` (unloaded) the zero; return the offset."""
        if n_samples < 1:
            raise DeviceError(f"taring {self.label} needs at least 1 sample, got {n_samples}")
        raw: list[np.ndarray] = []
        while len(raw) < n_samples:
            sample = self.read(timeout_s)
            if sample is None:
                raise DeviceError(
                    f"{self.label} sent no sample for {timeout_s} s while taring "
                    f"({len(raw)}/{n_samples} collected)"
                )
            raw.append(sample.force_n + self.offset_n)
        self.offset_n = np.mean(raw, axis=0)
        return self.offset_n.copy()

    def describe(self) -> dict[str, object]:
        """Static facts about the device for session metadata (with the tare offset)."""
        return {
            "kind": type(self).__name__,
            "rate_hz": self.rate_hz,
            "axes": list(self.axes),
            "offset_n": self.offset_n.tolist(),
        }
