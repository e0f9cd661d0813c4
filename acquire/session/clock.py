"""Clock synchronization: map each device's clock onto the host clock (kept apart from data).

Transport delay only ever adds latency, so the host time of a sample is the device time mapped
through a line plus a non-negative delay. :func:`fit_clock` takes the slope (drift) from the
*lower envelope* of the (device, host) pairs: a first Theil–Sen line, then repeated least-squares
fits through the lowest-residual pair of each time segment — or, when the delays scatter
symmetrically so that a least-squares line through all pairs is better determined, from that
line (the standard errors decide). The mapping then runs through the
*median* arrival (the envelope shifted by the median residual above it): every stream is mapped to
its typical arrival time, so the offset left between two mapped streams is the difference of
their median transport delays, whatever the number of samples (the envelope's own level, the
minimum of each segment's delays, sinks as segments get longer). What remains about the line is
transport jitter.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

_SEGMENTS = 32  # at most this many lower-envelope support points per fit
_POINTS_PER_SEGMENT = 16  # enough samples that each segment's minimum is near the true delay
NO_CLOCK_NS = -1  # t_device_ns of devices without a clock
_THEIL_SEN_PAIRS = 2000


@dataclass(frozen=True)
class ClockFit:
    """``t_host = ref_host_ns + intercept_ns + slope * (t_device - ref_device_ns)``: the median
    host arrival of a sample stamped ``t_device``."""

    ref_device_ns: int
    ref_host_ns: int
    intercept_ns: float
    slope: float
    jitter_ns: float  # robust spread (1.4826·MAD) of the host-time residuals about the envelope
    latency_ns: float  # median delay above the envelope (included in intercept_ns)
    n_pairs: int
    span_ns: int = 0  # device-time span of the pairs
    envelope_ns: float = 0.0  # scatter of the envelope's support points about the line
    drift_std_ppm: float = -1.0  # standard error of the drift (negative: from envelope_ns)

    @property
    def drift_uncertainty_ppm(self) -> float:
        """Standard error of :attr:`drift_ppm` (of the fit that set the slope)."""
        if self.drift_std_ppm >= 0:
            return self.drift_std_ppm
        if self.span_ns <= 0:
            return float("inf") if self.n_pairs > 1 else 0.0
        return 1e6 * self.envelope_ns * np.sqrt(12.0 / _n_segments(self.n_pairs)) / self.span_ns

    @property
    def drift_ppm(self) -> float:
        """How much faster the device clock runs than the host clock, in parts per million."""
        return (1.0 / self.slope - 1.0) * 1e6 if self.slope else 0.0

    @property
    def offset_ns(self) -> int:
        """Host time minus device time at the reference point."""
        return int(self.ref_host_ns + round(self.intercept_ns) - self.ref_device_ns)

    def to_host(self, t_device_ns: np.ndarray) -> np.ndarray:
        """Device timestamps (int64 ns) mapped onto the host clock (int64 ns)."""
        dt = (np.asarray(t_device_ns, dtype=np.int64) - self.ref_device_ns).astype(np.float64)
        return self.ref_host_ns + np.round(self.intercept_ns + self.slope * dt).astype(np.int64)

    def to_attrs(self) -> dict[str, float | int]:
        """Plain values to store as HDF5 attributes (plus the derived drift and offset)."""
        return {**asdict(self), "drift_ppm": self.drift_ppm, "offset_ns": self.offset_ns}

    @classmethod
    def from_attrs(cls, attrs: dict) -> ClockFit:
        """Rebuild a fit from :meth:`to_attrs` output (extra keys are ignored)."""
        return cls(
            int(attrs["ref_device_ns"]),
            int(attrs["ref_host_ns"]),
            float(attrs["intercept_ns"]),
            float(attrs["slope"]),
            float(attrs["jitter_ns"]),
            float(attrs["latency_ns"]),
            int(attrs["n_pairs"]),
            int(attrs.get("span_ns", 0)),
            float(attrs.get("envelope_ns", 0.0)),
            float(attrs.get("drift_std_ppm", -1.0)),
        )


def identity_fit(t_host_ns: np.ndarray) -> ClockFit:
    """The fit of a device without its own clock: its samples carry host time already."""
    ref = int(t_host_ns[0]) if len(t_host_ns) else 0
    return ClockFit(ref, ref, 0.0, 1.0, 0.0, 0.0, int(len(t_host_ns)))


def _theil_sen(x: np.ndarray, y: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
    n = len(x)
    i = rng.integers(0, n, _THEIL_SEN_PAIRS)
    j = rng.integers(0, n, _THEIL_SEN_PAIRS)
    keep = np.abs(x[j] - x[i]) > (x[-1] - x[0]) / 4  # well-separated pairs only
    if not keep.any():
        keep = x[j] != x[i]
    slope = float(np.median((y[j] - y[i])[keep] / (x[j] - x[i])[keep])) if keep.any() else 1.0
    return float(np.median(y - slope * x)), slope


def _n_segments(n_pairs: int) -> int:
    return int(min(np.clip(n_pairs // _POINTS_PER_SEGMENT, 2, _SEGMENTS), max(n_pairs, 1)))


def _envelope_fit(x: np.ndarray, y: np.ndarray, a: float, b: float) -> tuple[float, float, float]:
    """Line through the lowest point of each segment: ``(intercept, slope, scatter)``."""
    segments = np.array_split(np.arange(len(x)), _n_segments(len(x)))
    residual = y - (a + b * x)
    lowest = np.array([seg[np.argmin(residual[seg])] for seg in segments if len(seg)])
    if len(lowest) < 3 or np.ptp(x[lowest]) == 0:
        return float(np.min(residual) + a), b, float(np.std(residual))
    b, a = np.polyfit(x[lowest], y[lowest], 1)
    scatter = float(np.std(y[lowest] - (a + b * x[lowest]), ddof=2))
    return float(a), float(b), scatter


def fit_clock(t_device_ns: np.ndarray, t_host_ns: np.ndarray) -> ClockFit:
    """Fit host time against device time: drift from the lower envelope of the pairs, offset
    through their median arrival.

    A stream without a device clock (all ``t_device_ns == -1``) gets the identity on host time.
    """
    dev = np.asarray(t_device_ns, dtype=np.int64)
    host = np.asarray(t_host_ns, dtype=np.int64)
    if len(dev) == 0 or np.all(dev == NO_CLOCK_NS):
        return identity_fit(host)
    if len(dev) == 1:
        return ClockFit(int(dev[0]), int(host[0]), 0.0, 1.0, 0.0, 0.0, 1)
    order = np.argsort(dev, kind="stable")
    dev, host = dev[order], host[order]
    ref_dev, ref_host = int(dev[0]), int(host[0])
    x = (dev - ref_dev).astype(np.float64)
    y = (host - ref_host).astype(np.float64)
    a, b = _theil_sen(x, y, np.random.default_rng(0))
    for _ in range(3):
        a, b, scatter = _envelope_fit(x, y, a, b)
    span = float(x[-1] - x[0])
    slope_std = scatter * np.sqrt(12.0 / _n_segments(len(x))) / span if span > 0 else np.inf
    b_all, all_std = _trimmed_line(x, y, b)
    if all_std < slope_std:  # symmetric jitter: every pair says more than the envelope's minima
        b, slope_std = b_all, all_std
    residual = y - b * x
    segments = np.array_split(residual, _n_segments(len(x)))
    level = float(np.mean([seg.min() for seg in segments if len(seg)]))  # the envelope
    med = float(np.median(residual))
    jitter = 1.4826 * float(np.median(np.abs(residual - med)))
    return ClockFit(
        ref_dev,
        ref_host,
        med,
        b,
        jitter,
        med - level,
        int(len(dev)),
        int(dev[-1] - dev[0]),
        scatter,
        float(1e6 * slope_std / b**2) if np.isfinite(slope_std) else -1.0,
    )


def _trimmed_line(x: np.ndarray, y: np.ndarray, slope: float) -> tuple[float, float]:
    """Least-squares slope through all pairs within 5 robust sigmas of the line of ``slope``
    (host stalls left out), and its standard error."""
    residual = y - slope * x
    centre = float(np.median(residual))
    sigma = 1.4826 * float(np.median(np.abs(residual - centre))) or 1.0
    keep = np.abs(residual - centre) <= 5 * sigma
    if keep.sum() < 3 or np.ptp(x[keep]) == 0:
        return slope, np.inf
    b, a = np.polyfit(x[keep], y[keep], 1)
    spread = float(np.std(y[keep] - (a + b * x[keep]), ddof=2))
    return float(b), spread / np.sqrt(np.sum((x[keep] - x[keep].mean()) ** 2))
