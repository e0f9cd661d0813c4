"""What every device has, written once: open/close guards and the timed, sequenced read.

Backends implement small hooks, in the manner of python-can's ``BusABC.recv`` calling
``_recv_internal``: ``_open``/``_close`` acquire and release the hardware, and a streaming
device's ``_read_sample(timeout_s)`` returns one sample (or ``None``). The public methods do the
generic work once: idempotent open/close, the "not open" guard, the deadline loop, a failure that
stays raised once the device is gone, sequence tracking with drop and gap counting.
"""

from __future__ import annotations

import abc
import logging
import time
from typing import Generic, Protocol, TypeVar

from vbfe.common.closing import ClosedOnExit
from vbfe.common.errors import DeviceError
from vbfe.drivers.samples import StreamStats

log = logging.getLogger(__name__)

_D = TypeVar("_D", bound="Device")


class _Sequenced(Protocol):
    @property
    def seq(self) -> int: ...


S = TypeVar("S", bound=_Sequenced)  # a sample type with a ``seq`` attribute


class Device(ClosedOnExit):
    """A device that is acquired by ``open`` and released by ``close`` (both idempotent).
    ``stream`` names the session stream a readable device feeds (``None``: not read by an
    acquisition, e.g. a projector)."""

    stream: str | None = None
    _is_open = False

    @property
    def is_open(self) -> bool:
        """Whether ``open`` succeeded and ``close`` has not been called since."""
        return self._is_open

    @property
    def label(self) -> str:
        """How messages name the device (backends add where it is)."""
        return type(self).__name__

    def open(self) -> None:
        """Acquire the device; idempotent."""
        if not self._is_open:
            self._open()
            self._is_open = True
            log.info("%s opened", self.label)

    def close(self) -> None:
        """Release the device; idempotent."""
        if self._is_open:
            self._is_open = False
            self._close()
            log.info("%s closed", self.label)

    def require_open(self) -> None:
        """Raise DeviceError naming the device unless it is open."""
        if not self._is_open:
            raise DeviceError(f"{self.label} is not open; call open() first")

    @abc.abstractmethod
    def _open(self) -> None:
        """Backend hook: acquire the hardware (called once per open)."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Backend hook: release the hardware (called once per close)."""

    def __enter__(self: _D) -> _D:
        self.open()
        return self


class SampleStream(Device, Generic[S]):
    """A device delivering sequence-numbered samples through :meth:`read`.

    ``read`` blocks for at most ``timeout_s`` and returns ``None`` when nothing arrived in time;
    it raises :class:`DeviceError` when the device is gone, and keeps raising it afterwards.
    Sequence jumps count as drops (``stats.dropped``) and gaps (``stats.gaps``), less the
    samples that did arrive but were malformed (``stats.malformed``).
    """

    def __init__(self) -> None:
        self.stats = StreamStats()
        self._failure: DeviceError | None = None
        self._last_seq: int | None = None
        self._malformed_at_last = 0

    def open(self) -> None:
        """Acquire the device and start a fresh sequence; idempotent."""
        if not self.is_open:
            self._failure, self._last_seq = None, None
        super().open()

    def read(self, timeout_s: float = 1.0) -> S | None:
        """The next sample, ``None`` on timeout; DeviceError when the device is gone."""
        self.require_open()
        if self._failure is not None:
            raise self._failure
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                sample = self._read_sample(max(0.0, deadline - time.monotonic()))
            except DeviceError as exc:
                self._failure = exc
                raise
            if sample is not None:
                self._track(sample.seq)
                return self._finish(sample)
            if time.monotonic() >= deadline:
                return None

    @abc.abstractmethod
    def _read_sample(self, timeout_s: float) -> S | None:
        """Backend hook: one sample with the device's sequence number, or ``None`` when none
        arrived within ``timeout_s`` (or what arrived was not a sample; ``read`` retries while
        time is left). Raise DeviceError when the device is gone."""

    def _finish(self, sample: S) -> S:
        """What ``read`` returns for a tracked sample (the force sensor subtracts its tare)."""
        return sample

    def _track(self, seq: int) -> None:
        stats = self.stats
        stats.received += 1
        last = self._last_seq
        if last is not None and seq > last + 1:
            lost = seq - last - 1 - (stats.malformed - self._malformed_at_last)
            if lost > 0:
                stats.gaps.append((last, seq))
                stats.dropped += lost
                log.debug("%s: %d samples lost between seq %d and %d", self.label, lost, last, seq)
        self._last_seq, self._malformed_at_last = seq, stats.malformed
