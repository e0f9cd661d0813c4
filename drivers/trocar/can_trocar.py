"""The TRF85D force trocar on any python-can interface (socketcan, pcan, kvaser, virtual, ...)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from vbfe.common.errors import DeviceError
from vbfe.drivers.samples import ForceSample
from vbfe.drivers.trocar.base import ForceSensor
from vbfe.drivers.trocar.can_clock import (
    HOST_CLOCK,
    INTERFACE_CLOCKS,
    check_clock_choice,
    interface_stamps,
)
from vbfe.drivers.trocar.dbc import (
    DEFAULT_FORCE_SIGNALS,
    DEFAULT_MESSAGE,
    MalformedFrame,
    load_frame_format,
)

log = logging.getLogger(__name__)

CAN_ERR_CRTL = 0x04  # error-class bits of a SocketCAN error frame (linux/can/error.h)
CAN_ERR_BUSOFF = 0x40  # controller went bus-off
CAN_ERR_RESTARTED = 0x100  # controller restarted
BUS_STATE_BITS = CAN_ERR_CRTL | CAN_ERR_RESTARTED  # controller state changes (warning, passive)


class CanTrocar(ForceSensor):
    """Force samples decoded with cantools from CAN frames described by a DBC file.

    Device time is the message's interface timestamp when python-can's interface gives one
    (see :mod:`can_clock`; ``clock = "auto"`` takes it when the first frame carries one,
    ``"interface"`` insists on it, ``"host"`` never uses it), else the host receive time;
    ``describe()["device_clock"]`` says which. ``t_host_ns`` is ``host_clock()`` when the frame
    was read. Counter jumps count as lost samples in the base class; frames with the force
    message's ID that fail length/checksum/decoding count in ``stats.malformed``; error frames
    and controller state changes count in ``stats.errors`` and are marked as gaps.
    """

    def __init__(
        self,
        interface: str = "socketcan",
        channel: str = "can0",
        bitrate: int | None = None,
        dbc: str | Path | None = None,
        message: str = DEFAULT_MESSAGE,
        rate_hz: float = 1000.0,
        host_clock: Callable[[], int] = time.monotonic_ns,
        bus: can.BusABC | None = None,
        force_signals: tuple[str, ...] = DEFAULT_FORCE_SIGNALS,
        counter_signal: str | None = "Counter",
        checksum_signal: str | None = "Checksum",
        clock: str = "auto",
    ) -> None:
        super().__init__()
        self.format = load_frame_format(
            dbc, message, tuple(force_signals), counter_signal or None, checksum_signal or None
        )
        self.interface, self.channel, self.bitrate = interface, str(channel), bitrate
        self.dbc_path = str(dbc) if dbc is not None else "trf85d.dbc (shipped)"
        self.rate_hz = float(rate_hz)
        self.clock = check_clock_choice(clock)
        self._host_clock = host_clock
        self._external_bus = bus
        self._bus: can.BusABC | None = None
        self._seq: int | None = None
        self._last_rx_s = 0.0
        self._use_interface_time: bool | None = None  # decided at the first frame in "auto"

    @property
    def label(self) -> str:
        """The trocar and its CAN interface."""
        return f"trocar on CAN {self.interface} channel {self.channel!r}"

    @property
    def device_clock(self) -> str:
        """What ``t_device_ns`` is: the interface's timestamp (which one) or host receive time."""
        if self._use_interface_time is None:
            if self.clock == "host" or not interface_stamps(self.interface):
                return HOST_CLOCK
            return (
                f"interface timestamp if the first frame carries one ({self.clock}): "
                f"{INTERFACE_CLOCKS[self.interface]}; else {HOST_CLOCK}"
            )
        if self._use_interface_time:
            return INTERFACE_CLOCKS.get(self.interface, f"{self.interface} interface timestamp")
        return HOST_CLOCK

    def _open(self) -> None:
        """Connect to the CAN interface (or adopt the bus given to the constructor)."""
        self._seq, self._use_interface_time = None, None
        if self.clock == "host":
            self._use_interface_time = False
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
                f"cannot open {self.label}: {exc}; check the adapter is plugged in "
                f"and, for socketcan, bring it up with 'sudo ip link set {self.channel} up type "
                "can bitrate 1000000'"
            ) from None

    def _close(self) -> None:
        """Release the bus (a bus passed in by the caller stays open)."""
        if self._bus is not None and self._bus is not self._external_bus:
            self._bus.shutdown()
        self._bus = None

    def _open_bus(self) -> can.BusABC:
        if self._bus is None:
            raise DeviceError(f"{self.label} is not open")
        return self._bus

    def _read_sample(self, timeout_s: float) -> ForceSample | None:
        """Receive one CAN message; the raw force sample it carries, if it is one."""
        try:
            msg = self._open_bus().recv(timeout=timeout_s)
        except (can.CanError, OSError) as exc:
            raise DeviceError(
                f"{self.label} stopped: {exc}; check the cable, "
                "termination and that the interface is up"
            ) from None
        if msg is None:
            return None
        return self._accept(msg, self._host_clock())

    def describe(self) -> dict[str, object]:
        """Static facts for session metadata: interface, channel, DBC, message, resolution and
        the clock of ``t_device_ns``."""
        return {
            **super().describe(),
            "interface": self.interface,
            "channel": self.channel,
            "dbc": self.dbc_path,
            "message": self.format.message.name,
            "frame_id": self.format.frame_id,
            "resolution_n": self.format.resolution_n,
            "clock_option": self.clock,
            "device_clock": self.device_clock,
            "bus_errors": self.stats.errors,
        }

    def _count_malformed(self, reason: str) -> None:
        self.stats.malformed += 1
        n = self.stats.malformed
        if n <= 10 or n % 1000 == 0:
            log.warning("%s: malformed frame #%d (%s)", self.label, n, reason)

    def _bus_error(self, msg: can.Message, t_host_ns: int) -> None:
        """Count an error frame or controller state change and mark it as a gap."""
        if msg.arbitration_id & CAN_ERR_BUSOFF:
            raise DeviceError(
                f"{self.label}: controller is bus-off; check "
                "wiring, termination and bitrate, then restart the interface"
            )
        self.stats.errors += 1
        reason = "bus state change" if msg.arbitration_id & BUS_STATE_BITS else "device error"
        last = -1 if self._seq is None else self._seq
        self.stats.mark_gap(reason, last, -1, t_host_ns, 1)
        if self.stats.errors <= 10:
            log.warning(
                "%s: %s frame 0x%x data %s",
                self.label,
                reason,
                msg.arbitration_id,
                bytes(msg.data).hex(),
            )

    def _device_ns(self, msg: can.Message, t_host_ns: int) -> int | None:
        """The sample's device time on the clock chosen at the first frame; None if missing."""
        stamped = msg.timestamp > 0
        if self._use_interface_time is None:
            self._use_interface_time = (
                stamped and interface_stamps(self.interface) or (self.clock == "interface")
            )
        if not self._use_interface_time:
            return int(t_host_ns)
        return round(msg.timestamp * 1e9) if stamped else None

    def _accept(self, msg: can.Message, t_host_ns: int) -> ForceSample | None:
        if msg.is_error_frame:
            self._bus_error(msg, t_host_ns)
            return None
        if (
            msg.arbitration_id != self.format.frame_id
            or msg.is_remote_frame
            or msg.is_extended_id != self.format.message.is_extended_frame
        ):
            return None
        try:
            frame = self.format.decode(bytes(msg.data))
        except MalformedFrame as exc:
            self._count_malformed(str(exc))
            return None
        t_device_ns = self._device_ns(msg, t_host_ns)
        if t_device_ns is None:
            self._count_malformed("no interface timestamp")
            return None
        seq = self._sequence(frame.counter, t_host_ns / 1e9)
        if seq is None:
            self._count_malformed(f"repeated counter {frame.counter}")
            return None
        return ForceSample(
            force_n=frame.force_n, seq=seq, t_device_ns=t_device_ns, t_host_ns=int(t_host_ns)
        )

    def _sequence(self, counter: int | None, rx_s: float) -> int | None:
        """Unwrap the rolling counter into a sample number; None for a repeat."""
        last, last_rx_s = self._seq, self._last_rx_s
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
        self._seq, self._last_rx_s = seq, rx_s
        return seq
