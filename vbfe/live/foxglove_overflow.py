"""Which Foxglove clients fell behind, as foxglove-sdk reports them.

foxglove-sdk queues ``message_backlog_size`` messages per client and, when a client reads
slower than the server sends, drops that client's oldest without counting them. What it does
say is a log line of its Rust core, ``outbox for client ADDR full``, passed to Python's
``logging`` by pyo3-log under the logger :data:`SDK_LOGGER` (at most one such line every 30 s
for all clients together: a second client falling behind within 30 s of the first goes
unnamed). :class:`Overflows` listens for those lines while a server runs.
"""

from __future__ import annotations

import logging
import re
import threading

SDK_LOGGER = "foxglove.websocket.connected_client.send_lossy"
_LINE = re.compile(r"outbox for client (\S+) full")


class Overflows(logging.Handler):
    """The addresses of the clients whose queue filled, in the order reported; :meth:`new`
    hands each one over once (to tell the clients)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.clients: list[str] = []
        self._told = 0
        self._lock_clients = threading.Lock()
        self._level = logging.NOTSET  # the SDK logger's own level, put back on detach

    def emit(self, record: logging.LogRecord) -> None:
        match = _LINE.search(record.getMessage())
        if match is not None:
            with self._lock_clients:
                if match[1] not in self.clients:
                    self.clients.append(match[1])

    def new(self) -> list[str]:
        """The clients reported since the last call."""
        with self._lock_clients:
            fresh = self.clients[self._told :]
            self._told = len(self.clients)
        return fresh

    def attach(self) -> None:
        """Listen to foxglove-sdk's overflow lines (its logger set to INFO: pyo3-log passes a
        Rust line on only where the Python logger is enabled for its level)."""
        logger = logging.getLogger(SDK_LOGGER)
        self._level = logger.level
        logger.setLevel(logging.INFO)
        logger.addHandler(self)

    def detach(self) -> None:
        """Stop listening; the SDK logger gets its own level back."""
        logger = logging.getLogger(SDK_LOGGER)
        logger.removeHandler(self)
        logger.setLevel(self._level)
