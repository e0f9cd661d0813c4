"""A fake serial projector on a pty pair speaking the shipped ``commands.toml`` protocol.

``port`` is a real tty path (the pty's slave side) that ``SerialProjector`` opens like any
serial port; a thread on the master side answers each line. ``silent=True`` never answers.
"""

from __future__ import annotations

import os
import re
import select
import tty

from tests.fakes.threaded import ThreadedFake


class FakeSerialProjector(ThreadedFake):
    """Answers POWER / PATTERN / BRIGHTNESS / STATUS? lines with OK / ERR replies."""

    def __init__(self, silent: bool = False, n_patterns: int = 3) -> None:
        super().__init__(name="fake-serial-projector")
        self.silent, self.n_patterns = silent, n_patterns
        self.received: list[str] = []
        self.power, self.pattern, self.brightness = False, 0, 100
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)

    def answer(self, line: str) -> str:
        """The reply of the imaginary projector to one command line."""
        if line == "POWER ON" or line == "POWER OFF":
            self.power = line.endswith("ON")
            return "OK"
        if (m := re.fullmatch(r"PATTERN (\d+)", line)) is not None:
            if int(m[1]) >= self.n_patterns:
                return f"ERR no stored pattern {m[1]}"
            self.pattern = int(m[1])
            return f"OK PATTERN {self.pattern}"
        if (m := re.fullmatch(r"BRIGHTNESS (-?\d+)", line)) is not None:
            if not 0 <= int(m[1]) <= 100:
                return "ERR brightness out of range 0..100"
            self.brightness = int(m[1])
            return "OK"
        if line == "STATUS?":
            state = "ON" if self.power else "STANDBY"
            return f"STATUS {state} PATTERN {self.pattern} BRIGHTNESS {self.brightness}"
        return f"ERR unknown command {line}"

    def _cleanup(self) -> None:
        os.close(self._master)
        os.close(self._slave)

    def _run(self) -> None:
        pending = ""
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.02)
            if not ready:
                continue
            pending += os.read(self._master, 1024).decode("ascii", errors="replace")
            *lines, pending = re.split(r"\r\n|\r|\n", pending)
            for line in filter(None, lines):
                self.received.append(line)
                if not self.silent:
                    os.write(self._master, (self.answer(line) + "\r\n").encode("ascii"))
