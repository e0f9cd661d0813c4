"""A projector driven over a serial port (RS-232/USB) with a configurable command table.

The table (TOML, see the shipped ``commands.toml``) maps command names to templates and the
regexes of their acknowledgements, and pattern names to the projector's stored pattern numbers.
Ports are opened with ``serial.serial_for_url``, so ``/dev/ttyUSB0``, a pty path and URLs such as
``loop://`` or ``socket://host:port`` all work.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import serial

from vbfe.common.config import read_toml
from vbfe.common.errors import DeviceError
from vbfe.drivers.projector.base import Projector

log = logging.getLogger(__name__)
_LINE_END = re.compile(r"\r\n|\r|\n")


def default_commands_path() -> Path:
    """The command table shipped with vbfe (a generic ASCII line protocol)."""
    return Path(str(resources.files("vbfe.drivers.projector").joinpath("commands.toml")))


@dataclass(frozen=True)
class CommandSpec:
    """One command: what to send and how its success and error replies look."""

    send: str
    ack: re.Pattern[str]
    error: re.Pattern[str]


@dataclass(frozen=True)
class CommandTable:
    """A projector's serial protocol as read from a command-table TOML file."""

    path: Path
    line_ending: str
    encoding: str
    timeout_s: float
    commands: dict[str, CommandSpec]
    patterns: dict[str, int]
    on_open: tuple[str, ...]
    on_close: tuple[str, ...]

    @classmethod
    def load(cls, path: str | Path | None = None) -> CommandTable:
        """Read and check a command table; DeviceError naming the file when it is wrong."""
        path = Path(path) if path is not None else default_commands_path()
        data = read_toml(path, "projector command table", DeviceError)
        try:
            proto = data.get("protocol", {})
            ack, error = proto.get("ack", r"^OK\b"), proto.get("error", r"^ERR\s*(?P<reason>.*)$")
            commands = {
                name: CommandSpec(
                    spec["send"],
                    re.compile(spec.get("ack", ack)),
                    re.compile(spec.get("error", error)),
                )
                for name, spec in data.get("commands", {}).items()
            }
            table = cls(
                path=path,
                line_ending=proto.get("line_ending", "\r\n"),
                encoding=proto.get("encoding", "ascii"),
                timeout_s=float(proto.get("timeout_s", 1.0)),
                commands=commands,
                patterns={k: int(v) for k, v in data.get("patterns", {}).items()},
                on_open=tuple(proto.get("on_open", ())),
                on_close=tuple(proto.get("on_close", ())),
            )
        except (KeyError, TypeError, ValueError, re.error) as exc:
            raise DeviceError(
                f"projector command table {path} is malformed ({exc!r}); see the "
                "format described in the shipped commands.toml"
            ) from None
        unknown = [c for c in (*table.on_open, *table.on_close) if c not in commands]
        if unknown:
            raise DeviceError(
                f"projector command table {path}: on_open/on_close name unknown "
                f"command(s) {unknown}"
            )
        return table


class SerialProjector(Projector):
    """A projector with stored patterns, selected over a serial line.

    ``show(image, name)`` cannot send the image: it selects the stored pattern ``name`` from the
    table's ``[patterns]``. Events carry ``frame_id = -1`` (no frame-ID stamp over serial).
    """

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        commands: str | Path | None = None,
        timeout_s: float | None = None,
        width: int = 1280,
        height: int = 720,
        host_clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        super().__init__(host_clock)
        self.port, self.baudrate = str(port), int(baudrate)
        self.table = CommandTable.load(commands)
        self.timeout_s = float(timeout_s) if timeout_s is not None else self.table.timeout_s
        self.width, self.height = int(width), int(height)
        self._serial: Any = None
        self._pending = ""

    @property
    def label(self) -> str:
        """The projector and its port."""
        return f"projector on {self.port}"

    def _open(self) -> None:
        """Open the port and send the table's ``on_open`` commands (e.g. power on)."""
        try:
            self._serial = serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=0.02)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(
                f"cannot open projector port {self.port}: {exc}; check the adapter "
                "is plugged in and that you may use it (group 'dialout')"
            ) from None
        try:
            for name in self.table.on_open:
                self._command(name)
        except DeviceError:
            self._close_port()
            raise

    def _close(self) -> None:
        """Send the ``on_close`` commands (failures are logged) and close the port."""
        for name in self.table.on_close:
            try:
                self._command(name)
            except DeviceError as exc:
                log.warning("%s", exc)
        self._close_port()

    def _close_port(self) -> None:
        self._serial.close()
        self._serial = None

    def command(self, name: str, **params: Any) -> dict[str, str]:
        """Send command ``name`` filled with ``params``; the named groups of its acknowledgement.

        Raises DeviceError naming the port on an error reply or when no acknowledgement arrives
        within the timeout.
        """
        self.require_open()
        return self._command(name, **params)

    def _command(self, name: str, **params: Any) -> dict[str, str]:
        try:
            spec = self.table.commands[name]
            line = spec.send.format(**params)
        except KeyError as exc:
            raise DeviceError(
                f"projector command {name!r} needs {exc} (table "
                f"{self.table.path}, commands: {sorted(self.table.commands)})"
            ) from None
        except ValueError as exc:
            raise DeviceError(f"projector command {name!r} cannot use {params}: {exc}") from None
        self._serial.reset_input_buffer()
        self._pending = ""
        try:
            self._serial.write((line + self.table.line_ending).encode(self.table.encoding))
            return self._await_reply(line, spec)
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(f"projector port {self.port} failed during {line!r}: {exc}") from None

    def _await_reply(self, line: str, spec: CommandSpec) -> dict[str, str]:
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            chunk = self._serial.read(max(1, self._serial.in_waiting))
            self._pending += chunk.decode(self.table.encoding, errors="replace")
            *lines, self._pending = _LINE_END.split(self._pending)
            for reply in filter(None, lines):
                if (bad := spec.error.search(reply)) is not None:
                    reason = bad.groupdict().get("reason") or reply
                    raise DeviceError(f"projector on {self.port} refused {line!r}: {reason}")
                if (good := spec.ack.search(reply)) is not None:
                    return good.groupdict()
                log.debug("projector on %s: skipped reply %r", self.port, reply)
        raise DeviceError(
            f"projector on {self.port} did not acknowledge {line!r} within "
            f"{self.timeout_s} s; check the cable, baud rate ({self.baudrate}) "
            "and that the projector is on"
        )

    def _show(self, pattern: np.ndarray, name: str, seq: int) -> int:
        """Select the stored pattern ``name`` (``pattern`` is only what it should look like)."""
        if name not in self.table.patterns:
            raise DeviceError(
                f"projector on {self.port} has no stored pattern {name!r} in "
                f"{self.table.path}; known: {sorted(self.table.patterns)}"
            )
        self._command("pattern", index=self.table.patterns[name])
        return -1

    def describe(self) -> dict[str, object]:
        """Static facts for session metadata: port, baud rate and command table."""
        return {
            **super().describe(),
            "port": self.port,
            "baudrate": self.baudrate,
            "commands": str(self.table.path),
            "patterns": dict(self.table.patterns),
        }
