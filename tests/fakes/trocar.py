"""A fake TRF85D on a python-can ``virtual`` bus: DBC-encoded frames from a force profile.

The fake runs a thread that sends one frame per sample at ``rate_hz`` (scaled by the clock
drift) and remembers exactly what it sent, so tests compare decoded forces sample by sample.
Open the reader (``fake.trocar()``) before ``start()``: a virtual bus only delivers frames to
buses that exist when they are sent.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import can
import numpy as np

from tests.fakes.threaded import ThreadedFake
from vbfe.drivers.pacing import sleep_until
from vbfe.drivers.trocar.can_trocar import CAN_ERR_BUSOFF, CanTrocar
from vbfe.drivers.trocar.dbc import load_frame_format


class FakeTrocar(ThreadedFake):
    """Sends ``profile(t_s)`` (+ noise) as TRF85D frames on virtual CAN channel ``channel``.

    ``corrupt_fraction`` of the frames get one flipped bit or a wrong length; sample numbers in
    ``drop_counters`` are never sent; after ``disconnect_after`` frames a bus-off error frame is
    sent and the fake stops. ``sent_forces_n`` maps sample number → force put in a valid frame,
    ``corrupt_samples`` and ``dropped_samples`` hold the sample numbers of the injected faults.
    """

    def __init__(
        self,
        channel: str,
        profile: Callable[[float], np.ndarray],
        rate_hz: float = 1000.0,
        noise_n: float = 0.0,
        corrupt_fraction: float = 0.0,
        drop_counters: tuple[int, ...] = (),
        disconnect_after: int | None = None,
        clock_drift_ppm: float = 0.0,
        seed: int = 0,
    ) -> None:
        super().__init__(name=f"fake-trocar-{channel}")
        self.channel, self.profile, self.rate_hz = channel, profile, float(rate_hz)
        self.noise_n, self.corrupt_fraction = noise_n, corrupt_fraction
        self.drop_counters = frozenset(drop_counters)
        self.disconnect_after, self.clock_drift_ppm = disconnect_after, clock_drift_ppm
        self.frame_format = load_frame_format()
        self.sent_forces_n: dict[int, np.ndarray] = {}
        self.corrupt_samples: set[int] = set()
        self.dropped_samples: set[int] = set()
        self.error: BaseException | None = None
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()

    @property
    def n_corrupt(self) -> int:
        """How many corrupted frames were sent."""
        with self._lock:
            return len(self.corrupt_samples)

    @property
    def n_samples(self) -> int:
        """How many samples the fake produced (sent valid, sent corrupt or dropped)."""
        with self._lock:
            return len(self.sent_forces_n) + len(self.corrupt_samples) + len(self.dropped_samples)

    def trocar(self, **kwargs: Any) -> CanTrocar:
        """A :class:`CanTrocar` on the same virtual channel (not yet opened)."""
        return CanTrocar(interface="virtual", channel=self.channel, rate_hz=self.rate_hz, **kwargs)

    def _frame(self, n: int, timestamp: float) -> can.Message | None:
        force = np.asarray(self.profile(n / self.rate_hz), dtype=float)
        if self.noise_n:
            force = force + self._rng.normal(0.0, self.noise_n, 3)
        force = np.clip(force, -32.0, 32.0)
        if n in self.drop_counters:
            with self._lock:
                self.dropped_samples.add(n)
            return None
        data = bytearray(self.frame_format.encode(force, counter=n))
        if self._rng.random() < self.corrupt_fraction:
            if self._rng.random() < 0.5:
                bit = int(self._rng.integers(0, 8 * len(data)))
                data[bit // 8] ^= 1 << (bit % 8)
            else:
                data = data[: int(self._rng.integers(0, len(data)))]
            with self._lock:
                self.corrupt_samples.add(n)
        else:
            with self._lock:
                self.sent_forces_n[n] = force
        return can.Message(
            arbitration_id=self.frame_format.frame_id,
            data=bytes(data),
            is_extended_id=False,
            timestamp=timestamp,
        )

    def _run(self) -> None:
        # Frames carry the time an ideal sensor would have sent them, so a stalled test thread
        # looks like a late reader (as on a real bus), not like a sensor that paused.
        period_s = 1.0 / (self.rate_hz * (1.0 + self.clock_drift_ppm * 1e-6))
        try:
            with can.Bus(
                interface="virtual", channel=self.channel, preserve_timestamps=True
            ) as bus:
                start_ns, wall_start, n = time.monotonic_ns(), time.time(), 0
                while not self._stop.is_set():
                    if self.disconnect_after is not None and n >= self.disconnect_after:
                        bus.send(
                            can.Message(
                                arbitration_id=CAN_ERR_BUSOFF,
                                is_error_frame=True,
                                is_extended_id=False,
                                data=bytes(8),
                                timestamp=wall_start + n * period_s,
                            )
                        )
                        self._stop.set()
                        break
                    sleep_until(start_ns + int(n * period_s * 1e9))
                    message = self._frame(n, timestamp=wall_start + n * period_s)
                    if message is not None:
                        bus.send(message)
                    n += 1
        except Exception as exc:  # surfaced to the test through .error
            self.error = exc
