"""The trocar's CAN frame format, read from a DBC file with cantools.

The shipped ``trf85d.dbc`` documents the assumed TRF85D layout (three forces, a rolling counter,
a checksum byte). A rig with different firmware passes its own DBC, message and signal names;
the counter and checksum signals are optional.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import cantools
import numpy as np
from cantools.database.can import Message

from vbfe.common.errors import DeviceError

DEFAULT_MESSAGE = "TRF85D_Force"
DEFAULT_FORCE_SIGNALS = ("Fx", "Fy", "Fz")


def default_dbc_path() -> Path:
    """The DBC shipped with vbfe describing the assumed TRF85D layout."""
    return Path(str(resources.files("vbfe.drivers.trocar").joinpath("trf85d.dbc")))


class MalformedFrame(ValueError):
    """A frame with the trocar's ID that cannot be decoded (wrong length, checksum, range)."""


def checksum(payload: bytes) -> int:
    """Bitwise NOT of the 8-bit sum of ``payload`` (the TRF85D checksum over the other bytes)."""
    return (~sum(payload)) & 0xFF


@dataclass(frozen=True)
class DecodedFrame:
    """The content of one valid force frame."""

    force_n: np.ndarray  # (3,) newtons, untared
    counter: int | None  # rolling counter value, None when the message has no counter


@dataclass(frozen=True)
class TrocarFrameFormat:
    """How force samples are packed into one CAN message."""

    message: Message
    force_signals: tuple[str, ...]
    counter_signal: str | None
    checksum_signal: str | None

    @property
    def frame_id(self) -> int:
        """The CAN arbitration ID of the force message."""
        return int(self.message.frame_id)

    @property
    def counter_modulo(self) -> int:
        """How many counter values there are before it wraps (0 without a counter)."""
        if self.counter_signal is None:
            return 0
        return 1 << self.message.get_signal_by_name(self.counter_signal).length

    @property
    def resolution_n(self) -> float:
        """Force per bit of the coarsest force signal, newtons."""
        return max(float(self.message.get_signal_by_name(s).scale) for s in self.force_signals)

    def _checksum_byte(self) -> int:
        assert self.checksum_signal is not None  # called only for messages with one
        return self.message.get_signal_by_name(self.checksum_signal).start // 8

    def _expected_checksum(self, data: bytes) -> int:
        index = self._checksum_byte()
        return checksum(data[:index] + data[index + 1 :])

    def decode(self, data: bytes) -> DecodedFrame:
        """Decode one payload; raises :class:`MalformedFrame` when it is not a valid sample."""
        if len(data) != self.message.length:
            raise MalformedFrame(f"length {len(data)} bytes, expected {self.message.length}")
        if self.checksum_signal is not None:
            got, want = data[self._checksum_byte()], self._expected_checksum(data)
            if got != want:
                raise MalformedFrame(f"checksum 0x{got:02x}, expected 0x{want:02x}")
        try:
            values: Any = self.message.decode(data, decode_choices=False)  # name -> number
        except (cantools.database.DecodeError, ValueError) as exc:
            raise MalformedFrame(f"cannot decode: {exc}") from None
        force = np.array([float(values[s]) for s in self.force_signals])
        counter = None if self.counter_signal is None else int(values[self.counter_signal])
        return DecodedFrame(force_n=force, counter=counter)

    def encode(self, force_n: np.ndarray, counter: int = 0) -> bytes:
        """Pack one sample the way the sensor would (the fake trocar and tests use this)."""
        values: dict[str, float | int] = {s.name: 0 for s in self.message.signals}
        values.update({s: float(f) for s, f in zip(self.force_signals, force_n, strict=False)})
        if self.counter_signal is not None:
            values[self.counter_signal] = counter % self.counter_modulo
        data = bytearray(self.message.encode(values, strict=True))
        if self.checksum_signal is not None:
            data[self._checksum_byte()] = self._expected_checksum(bytes(data))
        return bytes(data)


def load_frame_format(
    dbc: str | Path | None = None,
    message: str = DEFAULT_MESSAGE,
    force_signals: tuple[str, ...] = DEFAULT_FORCE_SIGNALS,
    counter_signal: str | None = "Counter",
    checksum_signal: str | None = "Checksum",
) -> TrocarFrameFormat:
    """Read the force message layout from ``dbc`` (default: the shipped TRF85D DBC).

    Raises :class:`DeviceError` naming the file when it is missing or unreadable, or when the
    message or one of the named signals is not in it.
    """
    path = Path(dbc) if dbc is not None else default_dbc_path()
    try:
        # a DBC file gives a CAN database (cantools types the result as any of its kinds)
        database: Any = cantools.database.load_file(str(path), database_format="dbc")
    except FileNotFoundError:
        raise DeviceError(
            f"trocar DBC file {path} does not exist; set the trocar option 'dbc' "
            "to your sensor's DBC or leave it out to use the shipped one"
        ) from None
    except Exception as exc:  # cantools raises several parser-specific types
        raise DeviceError(f"trocar DBC file {path} cannot be parsed: {exc}") from None
    try:
        msg = database.get_message_by_name(message)
    except KeyError:
        names = sorted(m.name for m in database.messages)
        raise DeviceError(
            f"trocar DBC file {path} has no message {message!r}; it has {names}; "
            "set the trocar option 'message'"
        ) from None
    present = {s.name for s in msg.signals}
    wanted = [*force_signals, *(s for s in (counter_signal, checksum_signal) if s is not None)]
    missing = [s for s in wanted if s not in present]
    if missing:
        raise DeviceError(
            f"message {message!r} in trocar DBC file {path} lacks signal(s) "
            f"{missing}; it has {sorted(present)}"
        )
    if checksum_signal is not None:
        sig = msg.get_signal_by_name(checksum_signal)
        if sig.length != 8 or sig.start % 8 or sig.byte_order != "little_endian":
            raise DeviceError(
                f"checksum signal {checksum_signal!r} in {path} must be one whole "
                "byte; pass checksum_signal=None if your sensor uses another scheme"
            )
    return TrocarFrameFormat(msg, tuple(force_signals), counter_signal, checksum_signal)
