"""The TRF85D force trocar on any python-can interface (socketcan, pcan, kvaser, virtual, ...)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import numpy as np

from vbfe.drivers.errors import DeviceError
from vbfe.drivers.samples import ForceSample
from vbfe.drivers.trocar.base import ForceSensor
from vbfe.drivers.trocar.dbc import (DEFAULT_FORCE_SIGNALS, DEFAULT_MESSAGE, MalformedFrame,
                                     load_frame_format)

log = logging.getLogger(__name__)

CAN_ERR_BUSOFF = 0x40  # error-class bit of a SocketCAN error frame: controller went bus-off


class CanTrocar(ForceSensor):
    """Force samples decoded with cantools from CAN frames described by a DBC file.

    Device time is the unwrapped rolling counter times the nominal sample period, so it runs on
    the sensor's own oscillator; ``t_host_ns`` is ``host_clock()`` when the frame was read.
    Counter jumps count as lost samples (``stats.dropped``, ``stats.gaps``); frames with the
    force message's ID that fail length/checksum/decoding count in ``stats.malformed``.
    """

    def __init__(self, interface: str = "socketcan", channel: str = "can0",
                 bitrate: int | None = None, dbc: str | Path | None = None,
                 message: str = DEFAULT_MESSAGE, rate_hz: float = 1000.0,
                 host_clock: Callable[[], int] = time.monotonic_ns, bus: can.BusABC | None = None,
                 force_signals: tuple[str, ...] = DEFAULT_FORCE_SIGNALS,
                 counter_signal: str | None = "Counter",
                 checksum_signal: str | None = "Checksum") -> None:
        super().__init__()
        self.format = load_frame_format(dbc, message, tuple(force_signals),
                                        counter_signal or None, checksum_signal or None)
        self.interface, self.channel, self.bitrate = interface, str(channel), bitrate
        self.dbc_path = str(dbc) if dbc is not None else "trf85d.dbc (shipped)"
        self.rate_hz = float(rate_hz)
        self._host_clock = host_clock
        self._external_bus = bus
        self._bus: can.BusABC | None = None
        self._last_seq: int | None = None
        self._last_rx_s = 0.0
        self._malformed_since_good = 0

    @property
    def _where(self) -> str:
        return f"CAN {self.interface} channel {self.channel!r}"

    def open(self) -> None:
        """Connect to the CAN interface (or adopt the bus given to the constructor)."""
        if self._bus is not None:
            return
        if self._external_bus is not None:
            self._bus = self._external_bus
            return
        kwargs: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.bitrate is not None:
            kwargs["bitrate"] = int(self.bitrate)
        try:
            self._bus = can.Bus(**kwargs)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            raise DeviceError(
                f"cannot open trocar on {self._where}: {exc}; check the adapter is plugged in "
                f"and, for socketcan, bring it up with 'sudo ip link set {self.channel} up type "
                "can bitrate 1000000'") from None

    def close(self) -> None:
        """Release the bus (a bus passed in by the caller stays open)."""
        if self._bus is not None and self._bus is not self._external_bus:
            self._bus.shutdown()
        self._bus = None

    def read(self, timeout_s: float = 1.0) -> ForceSample | None:
        """The next valid, tared force sample; ``None`` when none arrived within ``timeout_s``."""
        if self._bus is None:
            raise DeviceError(f"trocar on {self._where} is not open; call open() first")
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                msg = self._bus.recv(timeout=max(0.0, deadline - time.monotonic()))
            except (can.CanError, OSError) as exc:
                raise DeviceError(f"trocar on {self._where} stopped: {exc}; check the cable, "
                                  "termination and that the interface is up") from None
            if msg is None:
                return None
            sample = self._accept(msg, self._host_clock())
            if sample is not None or time.monotonic() > deadline:
                return sample

    def tare(self, n_samples: int = 500, timeout_s: float = 1.0) -> np.ndarray:
        """Make the mean of the next ``n_samples`` (unloaded) the zero; return the offset."""
        raw = []
        while len(raw) < n_samples:
            sample = self.read(timeout_s)
            if sample is None:
                raise DeviceError(f"trocar on {self._where} sent no sample for {timeout_s} s "
                                  f"while taring ({len(raw)}/{n_samples} collected)")
            raw.append(sample.force_n + self.offset_n)
        self.offset_n = np.mean(raw, axis=0)
        return self.offset_n.copy()

    def describe(self) -> dict[str, object]:
        """Static facts for session metadata: interface, channel, DBC, message and resolution."""
        return {**super().describe(), "interface": self.interface, "channel": self.channel,
                "dbc": self.dbc_path, "message": self.format.message.name,
                "frame_id": self.format.frame_id, "resolution_n": self.format.resolution_n,
                "offset_n": self.offset_n.tolist()}

    def _count_malformed(self, reason: str) -> None:
        self.stats.malformed += 1
        self._malformed_since_good += 1
        n = self.stats.malformed
        if n <= 10 or n % 1000 == 0:
            log.warning("trocar on %s: malformed frame #%d (%s)", self._where, n, reason)

    def _accept(self, msg: can.Message, t_host_ns: int) -> ForceSample | None:
        if msg.is_error_frame:
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                raise DeviceError(f"trocar on {self._where}: controller is bus-off; check "
                                  "wiring, termination and bitrate, then restart the interface")
            self._count_malformed(f"error frame 0x{msg.arbitration_id:x}")
            return None
        if (msg.arbitration_id != self.format.frame_id or msg.is_remote_frame
                or msg.is_extended_id != self.format.message.is_extended_frame):
            return None
        try:
            frame = self.format.decode(bytes(msg.data))
        except MalformedFrame as exc:
            self._count_malformed(str(exc))
            return None
        seq = self._sequence(frame.counter, float(msg.timestamp))
        if seq is None:
            self._count_malformed(f"repeated counter {frame.counter}")
            return None
        self.stats.received += 1
        return ForceSample(force_n=frame.force_n - self.offset_n, seq=seq,
                           t_device_ns=round(seq * 1e9 / self.rate_hz), t_host_ns=int(t_host_ns))

    def _sequence(self, counter: int | None, rx_s: float) -> int | None:
        """Unwrap the rolling counter into a sample number; record gaps. None for a repeat."""
        last, last_rx_s = self._last_seq, self._last_rx_s
        if last is None:
            seq = 0 if counter is None else counter
        elif counter is None:
            seq = last + 1
        else:
            modulo = self.format.counter_modulo
            step = (counter - last) % modulo
            elapsed = round((rx_s - last_rx_s) * self.rate_hz)
            if elapsed >= modulo:  # silent for longer than one wrap: the arrival time decides
                step += modulo * round((elapsed - step) / modulo)
            if step == 0:
                return None
            seq = last + step
            lost = step - 1 - self._malformed_since_good
            if lost > 0:
                self.stats.dropped += lost
                self.stats.gaps.append((last, seq))
        self._last_seq, self._last_rx_s, self._malformed_since_good = seq, rx_s, 0
        return seq
