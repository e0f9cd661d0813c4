"""Where vbfe's log records go: the CLI's stderr and ``--log-file`` handlers, and the lines a
recording keeps in its session.

Every module logs through ``logging.getLogger(__name__)`` under the ``vbfe`` logger (as
python-can logs under ``can``); nothing below the CLI configures handlers except
:class:`LogLines`, which a recording attaches for its own duration.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

ROOT = "vbfe"  # the logger every module's logger descends from
LINE_FORMAT = "%(asctime)s.%(msecs)03d %(levelname)s %(name)s: %(message)s"
DATE_FORMAT = "%Y-%m-%dT%H:%M:%S"
MAX_LINES = 20_000  # a session keeps at most this many log lines (then counts the rest)


def _formatter() -> logging.Formatter:
    formatter = logging.Formatter(LINE_FORMAT, DATE_FORMAT)
    formatter.converter = time.gmtime  # UTC, as the session's time attributes
    return formatter


def configure(verbosity: int = 0, log_file: str | Path | None = None) -> None:
    """The CLI's logging: warnings on stderr (``verbosity`` 1: information, 2: debug, -1:
    errors only) and, with ``log_file``, every information line appended to that file."""
    root = logging.getLogger(ROOT)
    for handler in [h for h in root.handlers if getattr(h, "_vbfe_cli", False)]:
        root.removeHandler(handler)
        handler.close()
    levels = {-1: logging.ERROR, 0: logging.WARNING, 1: logging.INFO}
    stderr = logging.StreamHandler()
    stderr.setLevel(levels.get(verbosity, logging.DEBUG))
    stderr.setFormatter(logging.Formatter("vbfe: %(levelname)s %(name)s: %(message)s"))
    handlers: list[logging.Handler] = [stderr]
    if log_file is not None:
        to_file = logging.FileHandler(log_file, encoding="utf-8")
        to_file.setLevel(logging.DEBUG if verbosity >= 2 else logging.INFO)
        to_file.setFormatter(_formatter())
        handlers.append(to_file)
    for handler in handlers:
        handler._vbfe_cli = True  # type: ignore[attr-defined]
        root.addHandler(handler)
    root.setLevel(min(h.level for h in handlers))


class LogLines(logging.Handler):
    """Collects the ``vbfe`` log lines (information and above) from any thread; the
    recording takes them with :meth:`take` and writes them into its session."""

    def __init__(self, limit: int = MAX_LINES) -> None:
        super().__init__(logging.INFO)
        self.setFormatter(_formatter())
        self.limit = limit
        self.skipped = 0  # lines past the limit
        self._lines: list[str] = []
        self._taken = 0
        self._level = logging.NOTSET
        self._guard = threading.Lock()

    def emit(self, record: logging.LogRecord) -> None:
        line = self.format(record)
        with self._guard:
            if len(self._lines) < self.limit:
                self._lines.append(line)
            else:
                self.skipped += 1

    def attach(self) -> None:
        """Collect from the ``vbfe`` logger (its level lowered to information meanwhile when it
        was higher)."""
        root = logging.getLogger(ROOT)
        self._level = root.level
        if root.getEffectiveLevel() > logging.INFO:
            root.setLevel(logging.INFO)
        root.addHandler(self)

    def detach(self) -> None:
        """Stop collecting (idempotent) and give the ``vbfe`` logger its level back."""
        root = logging.getLogger(ROOT)
        if self in root.handlers:
            root.removeHandler(self)
            if root.level == logging.INFO:
                root.setLevel(self._level)

    def take(self) -> list[str]:
        """The lines not taken before."""
        with self._guard:
            lines, self._taken = self._lines[self._taken :], len(self._lines)
        return lines
