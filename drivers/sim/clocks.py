"""Simulated clocks: each device counts time with its own offset and drift; transport adds latency.

True time is the bench's simulated time in ns (0 = start of the trial). A device stamps a sample
taken at true time ``t`` with ``offset + t·(1 + drift_ppm·1e-6)`` (rounded down to its tick);
the host receives it at ``t + latency + jitter`` (zero-mean Gaussian jitter clipped at ±3σ,
arrivals kept in order). The image-vs-force offset a sync tool must find is the difference of
the two latencies.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class DeviceClock:
    """A device's own clock: ``device_ns = offset_ns + true_ns · (1 + drift_ppm·1e-6)``."""

    offset_ns: int
    drift_ppm: float = 0.0
    tick_ns: int = 1

    def device_ns(self, true_ns: np.ndarray | int) -> np.ndarray:
        """Device timestamps (int64) of true times."""
        true = np.asarray(true_ns, np.int64)
        drift = np.rint(true.astype(np.float64) * (self.drift_ppm * 1e-6)).astype(np.int64)
        ticks = self.offset_ns + true + drift
        return ticks - ticks % self.tick_ns

    def true_ns(self, device_ns: np.ndarray | int) -> np.ndarray:
        """True times (int64) of device timestamps (exact up to one tick)."""
        elapsed = np.asarray(device_ns, np.int64) - self.offset_ns
        return np.rint(elapsed / (1 + self.drift_ppm * 1e-6)).astype(np.int64)


@dataclass
class Transport:
    """Delivery to the host: fixed ``latency_ns`` plus Gaussian jitter, order preserved."""

    latency_ns: int
    jitter_ns: float
    rng: np.random.Generator
    _last_host_ns: int = field(default=-(2**62), init=False, repr=False)

    def __post_init__(self) -> None:
        if self.latency_ns < 3 * self.jitter_ns:
            raise ValueError(
                f"latency {self.latency_ns} ns must be at least 3× jitter "
                f"{self.jitter_ns} ns so samples do not arrive before they exist"
            )

    def host_ns(self, true_ns: np.ndarray) -> np.ndarray:
        """Host arrival times (int64, non-decreasing) of samples taken at ``true_ns`` (sorted)."""
        true = np.asarray(true_ns, np.int64)
        jitter = np.clip(
            self.rng.normal(0.0, self.jitter_ns, true.shape),
            -3 * self.jitter_ns,
            3 * self.jitter_ns,
        )
        host = true + self.latency_ns + np.rint(jitter).astype(np.int64)
        host = np.maximum.accumulate(np.maximum(host, self._last_host_ns))
        if host.size:
            self._last_host_ns = int(host[-1])
        return host
