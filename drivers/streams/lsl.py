"""An LSL inlet as a rig device: resolved at open, read sample by sample on the host clock.

LSL time stamps are the publisher's ``local_clock()`` (on Linux the monotonic clock, vbfe's
host clock). Each pulled chunk is mapped to this host by adding the stream's latest
``time_correction()`` (zero for a publisher on this machine, its clock offset for one on
another), which is re-measured every ``correction_interval_s``; the measurements are kept apart
from the data (``LslStream.time_corrections``, in its description) so the session stores how
the mapping was made. liblsl's own post-processing stays off: the raw stamps are stored beside
the mapped ones.

What the stamps show is told apart from what the recorder lost. LSL has no sequence numbers and
does not drop samples on a live inlet, except when the inlet's buffer (``buffer_s``) fills
because it was not read: liblsl then drops the oldest. So a stamp gap at the head of a pull that
found the buffer full is samples *lost* (``stats.dropped``); any other stamp step over 1.5 sample
periods is a *late or irregular publisher* (:class:`PublisherTiming`): it sent nothing then.
"""

from __future__ import annotations

import collections
import functools
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.drivers.device import SampleStream
from vbfe.drivers.streams.records import StreamInfo, StreamSample
from vbfe.drivers.streams.settings import StreamSource

_CHUNK_SAMPLES = 4096
_OPEN_TIMEOUT_S = 5.0
_FIRST_CORRECTION_TIMEOUT_S = 2.0
_AMBIGUITY_WAIT_S = 0.25  # after the first match, how long to listen for a second one
_GAP_PERIODS = 1.5  # a stamp step longer than this many sample periods counts as a gap
_LOG_CONFIG = "[log]\nlevel = -3\n"  # liblsl prints only fatal errors; vbfe reports the rest
_USER_CONFIGS = ("lsl_api.cfg", "~/lsl_api/lsl_api.cfg", "/etc/lsl_api/lsl_api.cfg")


@functools.cache
def pylsl() -> Any:
    """The pylsl module, with liblsl's console logging turned down unless the lab has its own
    ``lsl_api.cfg`` (``LSLAPICFG`` or one of liblsl's standard places), which then applies."""
    import pylsl as module

    if not os.environ.get("LSLAPICFG") and not any(
        Path(p).expanduser().is_file() for p in _USER_CONFIGS
    ):
        module.set_config_content(_LOG_CONFIG)
    return module


@dataclass
class PublisherTiming:
    """Irregularities of a regular-rate publisher's own time stamps (not data lost): steps of
    more than 1.5 sample periods, the sample periods they span without a sample, the longest."""

    gaps: int = 0
    missing_periods: int = 0
    worst_gap_ns: int = 0

    def add(self, step_ns: int, period_ns: float) -> None:
        """Count one stamp step of ``step_ns`` (longer than 1.5 periods)."""
        self.gaps += 1
        self.missing_periods += int(round(step_ns / period_ns)) - 1
        self.worst_gap_ns = max(self.worst_gap_ns, int(step_ns))


def host_ns(lsl_seconds: float) -> int:
    """An LSL ``local_clock()`` time in host-clock nanoseconds."""
    return int(round(lsl_seconds * 1e9))


def _channels(info: Any, count: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Channel labels and units from the XDF-convention metadata ``desc/channels/channel``
    (``label``, ``unit``); ``ch0``, ``ch1``, … and "" where the stream gives none."""
    labels, units = [f"ch{i}" for i in range(count)], [""] * count
    channel = info.desc().child("channels").child("channel")
    for i in range(count):
        if channel.empty():
            break
        labels[i] = channel.child_value("label") or labels[i]
        units[i] = channel.child_value("unit")
        channel = channel.next_sibling("channel")
    return tuple(labels), tuple(units)


def describe_info(key: str, info: Any) -> StreamInfo:
    """A :class:`StreamInfo` from a pylsl ``StreamInfo`` with its full metadata."""
    labels, units = _channels(info, info.channel_count())
    return StreamInfo(
        name=key,
        lsl_name=info.name(),
        type=info.type(),
        source_id=info.source_id(),
        hostname=info.hostname(),
        channels=labels,
        units=units,
        nominal_rate_hz=float(info.nominal_srate()),
        markers=info.channel_format() == pylsl().cf_string,
        info_xml=info.as_xml(),
    )


def resolve(source: StreamSource) -> Any:
    """The one LSL stream ``source`` names, within its ``resolve_timeout_s``; DeviceError when
    none or several (then naming their source ids) are found."""
    found = pylsl().resolve_bypred(source.predicate(), minimum=1, timeout=source.resolve_timeout_s)
    if found:  # the first answer ends the wait: listen a little longer for a second publisher
        found += pylsl().resolve_bypred(source.predicate(), minimum=2, timeout=_AMBIGUITY_WAIT_S)
    if not found:
        raise DeviceError(
            f"stream {source.describe()} was not found on the network within "
            f"{source.resolve_timeout_s:g} s"
        )
    uids = {info.uid() for info in found}
    if len(uids) > 1:
        ids = ", ".join(sorted({repr(f"{i.source_id()}@{i.hostname()}") for i in found}))
        raise DeviceError(
            f"stream {source.describe()} matches {len(uids)} LSL streams ({ids}); "
            "add its source_id to tell them apart"
        )
    return found[0]


class LslStream(SampleStream[StreamSample]):
    """One extra stream read from LSL, sample by sample (pulled in chunks underneath).

    ``stats.dropped`` and ``stats.gaps`` count samples lost when the inlet's buffer overflowed
    (the oldest, dropped by liblsl); ``timing`` the publisher's own irregular stamps (module
    docstring). LSL has no sequence numbers, so ``seq`` counts the samples received.
    ``time_corrections`` is the history of ``(t_host_ns, correction_ns)`` measurements (in
    :meth:`describe`, stored with the session). ``stream`` is the session's name for it (what
    an acquisition files its records under)."""

    def __init__(self, source: StreamSource, correction_interval_s: float = 5.0) -> None:
        super().__init__()
        self.source = source
        self.missing: str | None = None  # why an optional stream was not opened
        self.correction_interval_s = correction_interval_s
        self.info: StreamInfo | None = None
        self.time_corrections: list[tuple[int, int]] = []
        self._inlet: Any = None
        self._buffer: collections.deque[StreamSample] = collections.deque()
        self._seq = 0
        self._last_stamp_ns: int | None = None
        self.timing = PublisherTiming()
        self._capacity = 0  # samples the inlet's buffer holds
        self._correction_ns = 0
        self._next_correction = 0.0

    @property
    def label(self) -> str:
        return f"LSL stream {self.source.describe()}"

    # the devices' class attribute, computed here: the stream is named only once it is found
    @property
    def stream(self) -> str | None:  # type: ignore[override]
        """The session's name for the stream; ``None`` while an optional stream is missing
        (an acquisition reads only devices that name a stream)."""
        return None if self.missing else self.source.key

    def _open(self) -> None:
        lsl = pylsl()
        self.missing = None
        try:
            found = resolve(self.source)
        except DeviceError as exc:
            if self.source.required:
                raise DeviceError(
                    f"{exc}; start its publisher (or mark it required = false)"
                ) from None
            self.missing = f"optional {exc}; recording without it"
            return
        buffer_s = max(1, round(self.source.buffer_s))
        self._inlet = lsl.StreamInlet(
            found, max_buflen=buffer_s, recover=True, processing_flags=lsl.proc_none
        )
        rate = found.nominal_srate()
        self._capacity = int(buffer_s * rate) if rate > 0 else buffer_s * 100  # as liblsl sizes it
        try:
            self._inlet.open_stream(timeout=_OPEN_TIMEOUT_S)
            self.info = describe_info(self.source.key, self._inlet.info(timeout=_OPEN_TIMEOUT_S))
            self.time_corrections = []
            self._measure_correction(_FIRST_CORRECTION_TIMEOUT_S)
        except (TimeoutError, lsl.util.LostError) as exc:
            self._inlet = None
            raise DeviceError(
                f"{self.label}: found but it does not answer ({exc}); is its "
                "publisher still running?"
            ) from None
        self._buffer.clear()
        self._seq, self._last_stamp_ns = 0, None
        self.timing = PublisherTiming()

    def _close(self) -> None:
        inlet, self._inlet = self._inlet, None
        if inlet is not None:
            inlet.close_stream()

    def _measure_correction(self, timeout_s: float) -> None:
        """Re-measure the publisher's clock offset (kept when the probe times out)."""
        try:
            correction_s = self._inlet.time_correction(timeout=timeout_s)
        except TimeoutError:
            return
        self._correction_ns = host_ns(correction_s)
        self.time_corrections.append((time.monotonic_ns(), self._correction_ns))
        self._next_correction = time.monotonic() + self.correction_interval_s

    def _read_sample(self, timeout_s: float) -> StreamSample | None:
        if self._inlet is None:
            raise DeviceError(self.missing or f"{self.label} is not open")
        if not self._buffer:
            self._pull(timeout_s)
        return self._buffer.popleft() if self._buffer else None

    def _pull(self, timeout_s: float) -> None:
        """Pull what arrived within ``timeout_s`` into the buffer, mapped to the host clock."""
        if time.monotonic() >= self._next_correction:
            self._measure_correction(0.0)
        overflowed = self._inlet.samples_available() >= self._capacity - 1
        values, stamps = self._inlet.pull_chunk(
            timeout=timeout_s, max_samples=_CHUNK_SAMPLES, min_samples=1, as_numpy=True
        )
        if len(stamps) == 0:
            return
        t_device = np.round(np.asarray(stamps, np.float64) * 1e9).astype(np.int64)
        t_host = t_device + self._correction_ns
        self._count_gaps(t_device, overflowed)
        rows: list[tuple[str | None, np.ndarray | None]]
        if self._info().markers:
            rows = [("\t".join(v.decode("utf-8", "replace") for v in row), None) for row in values]
        else:
            rows = [
                (None, row) for row in np.asarray(values, np.float64).reshape(len(t_device), -1)
            ]
        self._buffer.extend(
            StreamSample(
                values=row, text=text, seq=self._seq + i, t_device_ns=int(td), t_host_ns=int(th)
            )
            for i, ((text, row), td, th) in enumerate(zip(rows, t_device, t_host, strict=False))
        )
        self._seq += len(t_device)

    def _info(self) -> StreamInfo:
        """The stream's description, known once it is open."""
        if self.info is None:
            raise DeviceError(f"{self.label} is not open")
        return self.info

    def _count_gaps(self, t_device: np.ndarray, overflowed: bool) -> None:
        """Stamp steps over 1.5 periods: lost when it is the step into a pull that found the
        buffer full (liblsl dropped the oldest samples there), else the publisher's timing."""
        rate = self._info().nominal_rate_hz
        if rate <= 0:
            return
        stamps = (
            t_device
            if self._last_stamp_ns is None
            else np.concatenate([[self._last_stamp_ns], t_device])
        )
        period = 1e9 / rate
        head = self._last_stamp_ns is not None  # stamps[0] is the previous pull's last
        offset = self._seq - (1 if head else 0)
        steps = np.diff(stamps)
        for i in np.flatnonzero(steps > _GAP_PERIODS * period):
            if head and overflowed and i == 0:
                self.stats.dropped += int(round(steps[i] / period)) - 1
                self.stats.gaps.append((offset + int(i), offset + int(i) + 1))
            else:
                self.timing.add(int(steps[i]), period)
        self._last_stamp_ns = int(t_device[-1])

    def describe(self) -> dict[str, Any]:
        """JSON-able: what was asked for, what was found, the clock corrections measured."""
        out: dict[str, Any] = {
            "backend": "lsl",
            "predicate": self.source.predicate(),
            "required": self.source.required,
            "missing": self.missing,
        }
        if self.info is not None:
            out.update({k: v for k, v in vars(self.info).items() if k != "info_xml"})
            out["time_corrections"] = [list(c) for c in self.time_corrections]
            out["publisher_timing"] = vars(self.timing).copy()
        return out
