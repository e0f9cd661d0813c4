"""The acquisition: the one owner of a running rig's reader threads, in the manner of
pymeasure's Worker: per-device reader threads → bounded queues → one dispatch thread that hands
every record to the registered :class:`~vbfe.acquire.recording.listener.Listener`\\ s.

Lossy listeners (``Listener.lossy``: the live estimate, the viewers) are served apart, by a
dispatch thread of their own that the readers feed directly: the newest camera frame through a
one-slot mailbox (a frame not taken in time is replaced, counted in ``live_skipped``), the
other streams' records through a bounded queue (full: dropped, counted in ``live_dropped``).
They always see the newest frame, however far behind the writer is, and nothing they do
holds the recording back.

For a real-time device a full queue never blocks it: the record is dropped, counted and
reported as a gap. A device that describes itself as not real time (``describe()["realtime"]
is False``, the simulated bench run as fast as it renders) waits for room instead: the
dispatch paces it. A device that vanishes ends the acquisition cleanly with a reported gap. In
:meth:`Acquisition.run`, Ctrl-C and SIGTERM stop it; further ones while it is being finished
are ignored. An acquisition of a given duration keeps exactly the frames, and the samples of
the other streams, that arrived (host clock) before its end: when the duration is reached the
other readers go on until they have read past the end, so what is kept never depends on when
the threads happened to stop.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from vbfe.acquire.recording.listener import Gap, Listener
from vbfe.acquire.session.layout import CAMERA, FORCE, PROJECTOR
from vbfe.common.errors import DeviceError, SessionError
from vbfe.common.mailbox import Mailbox
from vbfe.drivers.projector.pattern import PATTERN_NAME
from vbfe.drivers.rig import Rig
from vbfe.drivers.samples import ProjectorEvent, StereoFrame

log = logging.getLogger(__name__)

_READ_TIMEOUT_S = 0.2
_FRAME_BATCH = 8  # at most this many frames a round: a writer behind catches up in batches
# (fewer rounds, each with the other streams and the listeners' periodic work)
_PUT_POLL_S = 0.1  # a paced device rechecks the stop flag this often while the queue is full
_END_GRACE_S = 2.0  # how long a reader may go on after the stop to reach the acquisition's end
_SAMPLE_QUEUE_FACTOR = 64  # streams other than the camera queue this many more (small) records

L = TypeVar("L", bound=Listener)
PatternSource = np.ndarray | Callable[[int, int], np.ndarray]


@dataclass
class AcquisitionStats:
    """Progress of an acquisition, as shown on the progress line."""

    elapsed_s: float = 0.0  # span of kept frame host times
    first_frame_host_ns: int = 0  # host time of the first kept frame
    newest_read_host_ns: int = 0  # host time of the newest frame read from the camera
    wall_s: float = 0.0
    counts: dict[str, int] = field(default_factory=dict)  # records dispatched per stream
    flushed: dict[str, int] = field(default_factory=dict)  # what a file sink made durable
    dropped: dict[str, int] = field(default_factory=dict)  # queue overflows + device-side drops
    queue_dropped: dict[str, int] = field(default_factory=dict)  # queue overflows alone
    live_skipped: int = 0  # frames no lossy listener saw (a newer one replaced them)
    live_dropped: int = 0  # other records dropped for the lossy listeners (their queue full)
    bytes_written: int = 0  # payload a file sink wrote
    end_reason: str = ""

    @property
    def frames(self) -> int:
        """Frames dispatched."""
        return self.counts.get(CAMERA, 0)

    @property
    def samples(self) -> int:
        """Force samples dispatched."""
        return self.counts.get(FORCE, 0)

    @property
    def events(self) -> int:
        """Projector events dispatched."""
        return self.counts.get(PROJECTOR, 0)

    @property
    def write_rate_mb_s(self) -> float:
        """Uncompressed payload written per wall-clock second, in MB/s."""
        return self.bytes_written / 1e6 / self.wall_s if self.wall_s > 0 else 0.0


class _Pump(threading.Thread):
    """Reads one device into a bounded queue; reports overflow and disconnection as gaps."""

    def __init__(
        self,
        stream: str,
        device: Any,
        out: queue.Queue,
        control: queue.Queue,
        stop: threading.Event,
        paced: bool = False,
        read_until_ns: Callable[[], int | None] = lambda: None,
        demand: threading.Semaphore | None = None,
        live: Callable[[str, Any], None] | None = None,
    ) -> None:
        super().__init__(name=f"vbfe-read-{stream}", daemon=True)
        self.stream, self._device, self._out = stream, device, out
        self._control, self._halt = control, stop
        self.paced = paced
        self._read_until_ns = read_until_ns
        self._demand = demand  # read only when a consumer asked (one read per release)
        self._live = live  # offered every item read, for the lossy listeners
        self.dropped = 0
        self.last_seq = -1
        self.last_t_host_ns = 0  # host time of the newest item read
        self.error: str | None = None
        self._halted_at: float | None = None

    def _gap(self, reason: str, last_seq: int, next_seq: int, t_host_ns: int, count: int) -> None:
        self._control.put(Gap(self.stream, reason, last_seq, next_seq, t_host_ns, count))

    def _done(self) -> bool:
        """Stopped, and past the acquisition's end (``read_until_ns``) when there is one."""
        if not self._halt.is_set():
            return False
        end_ns = self._read_until_ns()
        if end_ns is None or self.last_t_host_ns >= end_ns:
            return True
        if self._halted_at is None:
            self._halted_at = time.monotonic()
        return time.monotonic() - self._halted_at > _END_GRACE_S

    def run(self) -> None:
        burst = 0
        while not self._done():
            if self._demand is not None and not self._demand.acquire(timeout=_READ_TIMEOUT_S):
                continue
            try:
                item = self._device.read(_READ_TIMEOUT_S)
            except DeviceError as exc:
                self.error = str(exc)
                self._gap("device disconnected", self.last_seq, -1, time.monotonic_ns(), 0)
                break
            for mark in self._device.stats.take_marks():  # bus errors the device reported
                self._gap(mark.reason, mark.last_seq, mark.next_seq, mark.t_host_ns, mark.count)
            if item is None:
                if self._demand is not None:
                    self._demand.release()  # still owed
                continue
            self.last_t_host_ns = item.t_host_ns
            if self._live is not None:
                self._live(self.stream, item)
            try:
                if self.paced:
                    self._put_paced(item)
                    continue
                self._out.put_nowait(item)
            except queue.Full:
                self.dropped += 1
                burst += 1
                continue
            if burst:
                self._gap("queue full", self.last_seq, item.seq, item.t_host_ns, burst)
                burst = 0
            self.last_seq = item.seq
        if burst:  # records lost at the very end: no next sequence number
            self._gap("queue full", self.last_seq, -1, time.monotonic_ns(), burst)

    def _put_paced(self, item: Any) -> None:
        """Wait for room in the queue (the device is not real time: it waits, nothing drops;
        after a stop, only while the reader still has to reach the acquisition's end)."""
        while True:
            try:
                self._out.put(item, timeout=_PUT_POLL_S)
            except queue.Full:
                if self._done():
                    return
                continue
            self.last_seq = item.seq
            return


def _drain(q: queue.Queue, limit: int, timeout_s: float = 0.0) -> list[Any]:
    items = []
    try:
        items.append(q.get(timeout=timeout_s) if timeout_s else q.get_nowait())
        while len(items) < limit:
            items.append(q.get_nowait())
    except queue.Empty:
        pass
    return items


class Acquisition:
    """Read a rig's streams and hand every record to the listeners until :meth:`stop`.

    ``with Acquisition(rig) as acq: acq.add(listener); acq.run(duration_s)`` or call
    :meth:`start` / :meth:`stop` yourself. :meth:`start` opens the rig and :meth:`stop` closes
    it.

    :param rig: the devices to read (not opened yet).
    :param pattern: shown on the projector at the start when the rig has one: an image, or a
        function of the opened projector's ``(width, height)`` that makes one.
    :param pattern_name: the name the pattern's projector event is recorded under.
    :param queue_size: frames buffered per camera between its reader and the dispatch (other
        streams, and the lossy listeners' records, get proportionally more); a full queue
        drops records, marked as gaps.
    :param queue_bytes: the camera's queue holds as many frames as fit in this many bytes
        (uncompressed), when that is more than ``queue_size``: a writer short of CPU for a
        few seconds catches up instead of losing frames.
    :param listeners: consumers of the records, in dispatch order (more with :meth:`add`).
    :param on_demand: read the camera only when asked (:meth:`demand`, one frame each), for
        consumers in lock-step with the projector (show, then the frames after it).
    """

    def __init__(
        self,
        rig: Rig,
        pattern: PatternSource | None = None,
        pattern_name: str = PATTERN_NAME,
        queue_size: int = 256,
        listeners: tuple[Listener, ...] = (),
        on_demand: bool = False,
        queue_bytes: int = 0,
    ) -> None:
        self.rig = rig
        self.pattern, self.pattern_name = pattern, pattern_name
        self.listeners: list[Listener] = list(listeners)
        self.stats = AcquisitionStats()
        self.error: BaseException | None = None  # a record hook's failure, raised by stop()
        self.what = "the acquisition"  # how the Ctrl-C message names what is being finished
        self._queue_size, self._queue_bytes = queue_size, queue_bytes
        self._demand = threading.Semaphore(0) if on_demand else None
        self._queues: dict[str, queue.Queue] = {}
        self._control: queue.Queue = queue.Queue()
        self._halt = threading.Event()
        self._halt_reason: str | None = None
        self._stop_request: str | None = None
        self._pumps: list[_Pump] = []
        self._dispatcher: threading.Thread | None = None
        self._direct: list[Listener] = []  # served by the dispatch thread, every record
        self._lossy: list[Listener] = []  # served by the live dispatch thread
        self._live_frames: Mailbox[StereoFrame] = Mailbox()
        self._live_records: queue.Queue[tuple[str | None, Any]] = queue.Queue(
            queue_size * _SAMPLE_QUEUE_FACTOR
        )
        self._live_dropped = 0
        self._live_dispatcher: threading.Thread | None = None
        self._dispatch_done = threading.Event()
        self._started = self._stopped = False
        self.paced = False  # the camera is not real time: readers wait for room, nothing drops
        self._frame_t_host = [0, 0]  # first, last kept
        self._span_limit_ns: int | None = None
        self._span_reached = threading.Event()
        self._end_host_ns: int | None = None  # first frame's host time + duration
        self._t_start = 0.0

    def add(self, listener: L) -> L:
        """Register a listener before :meth:`start`.

        :param listener: the consumer to add after those already registered.
        :returns: ``listener`` itself.
        :raises SessionError: the acquisition has already started.
        """
        if self._started:
            raise SessionError("add listeners before the acquisition starts")
        self.listeners.append(listener)
        return listener

    # -- lifecycle ------------------------------------------------------------------------
    def start(self, duration_s: float | None = None) -> None:
        """Open the rig, show the pattern, start the listeners, the readers and the dispatch.

        :param duration_s: keep that many seconds of frames (host clock), then end; ``None``:
            until :meth:`stop`.
        :raises SessionError: ``duration_s`` is not positive.
        :raises DeviceError: a device cannot be opened (those opened are closed again).
        """
        if duration_s is not None:
            self._set_duration(duration_s)
        self.rig.open()
        started: list[Listener] = []
        try:
            self._show_initial_pattern()
            self._t_start = time.monotonic()
            self._started = True
            for listener in self.listeners:
                listener.on_start(self)
                started.append(listener)
        except BaseException:
            self._stopped = True  # nothing was read: the listeners started are stopped here
            self._halt.set()
            self.rig.close()
            for listener in started:
                with contextlib.suppress(Exception):
                    listener.on_stop(self)
            raise
        self._lossy = [listener for listener in self.listeners if listener.lossy]
        self._direct = [listener for listener in self.listeners if not listener.lossy]
        streams = dict(self.rig.streams())
        self.paced = any(
            d.describe().get("realtime") is False for s, d in streams.items() if s == CAMERA
        )
        for stream, device in streams.items():
            size = self._queue_size * (1 if stream == CAMERA else _SAMPLE_QUEUE_FACTOR)
            if stream == CAMERA:
                frame_bytes = 6 * device.width * device.height  # two BGR images
                size = max(size, self._queue_bytes // frame_bytes)
            self._queues[stream] = queue.Queue(maxsize=size)
            self._pumps.append(
                _Pump(
                    stream,
                    device,
                    self._queues[stream],
                    self._control,
                    self._halt,
                    self.paced,
                    (lambda: None) if stream == CAMERA else self._reached_end_ns,
                    self._demand if stream == CAMERA else None,
                    self._offer_live if self._lossy else None,
                )
            )
        self._dispatcher = threading.Thread(
            target=self._dispatch_loop, name="vbfe-dispatch", daemon=True
        )
        self._dispatcher.start()
        if self._lossy:
            self._live_dispatcher = threading.Thread(
                target=self._live_loop, name="vbfe-dispatch-live", daemon=True
            )
            self._live_dispatcher.start()
        for pump in self._pumps:
            pump.start()
        log.info(
            "acquisition started: streams %s%s",
            ", ".join(streams),
            " (paced: the camera is not real time)" if self.paced else "",
        )

    def _show_initial_pattern(self) -> None:
        if self.pattern is None or not self.rig.has("projector"):
            return
        projector = self.rig.projector
        if callable(self.pattern):  # sized now that the projector is open (an HDMI screen's)
            self.pattern = self.pattern(projector.width, projector.height)
        self.show(self.pattern, self.pattern_name)

    def demand(self) -> None:
        """Ask an ``on_demand`` acquisition for one more camera frame."""
        if self._demand is not None:
            self._demand.release()

    def show(self, pattern: np.ndarray, name: str) -> ProjectorEvent:
        """Put ``pattern`` on the projector now and dispatch the event (call from the thread
        that runs :meth:`run`, e.g. from a listener's ``on_tick``)."""
        event = self.rig.projector.show(pattern, name)
        self._control.put(event)
        if self._lossy:
            self._offer_live(PROJECTOR, event)
        return event

    def run(
        self,
        duration_s: float | None = None,
        on_progress: Callable[[AcquisitionStats], None] | None = None,
        progress_interval_s: float = 0.5,
        on_tick: Callable[[Acquisition, AcquisitionStats], None] | None = None,
    ) -> AcquisitionStats:
        """Run (starting first if needed) until ``duration_s`` of frames (host clock) are in, a
        device is gone, a listener halts it, Ctrl-C or SIGTERM; then stop cleanly.

        :param duration_s: seconds of frames to keep; ``None``: the duration given to
            :meth:`start`, else until stopped.
        :param on_progress: called with the statistics every ``progress_interval_s``.
        :param progress_interval_s: seconds between ``on_progress`` calls.
        :param on_tick: called every 50 ms with the acquisition and its statistics, after the
            listeners' ``on_tick``.
        :returns: the final statistics (its ``end_reason`` says why it ended).
        :raises SessionError: ``duration_s`` is not positive, or a listener failed (see
            :meth:`stop`).
        :raises DeviceError: a device cannot be opened.
        """
        if not self._started:
            self.start()
        last_progress = 0.0
        if duration_s is not None:
            try:
                self._set_duration(duration_s)
            except SessionError:
                self.stop()
                raise
        with self._signals_stop():
            while True:
                time.sleep(0.05)
                stats = self.update_stats()
                for listener in self.listeners:
                    listener.on_tick(self, stats)
                if on_tick is not None:
                    on_tick(self, stats)
                if on_progress is not None and stats.wall_s - last_progress >= progress_interval_s:
                    on_progress(stats)
                    last_progress = stats.wall_s
                reason = self.finished()
                if reason is not None:
                    if reason:
                        stats.end_reason = stats.end_reason or reason
                    break
            return self.stop()

    def finished(self) -> str | None:
        """Why the acquisition should end now (``""``: halted without a reason yet), or
        ``None`` while it runs."""
        if self._stop_request is not None:
            return self._stop_request
        if self._span_reached.is_set():
            return "duration reached"
        lost = self.lost()
        if lost:
            return lost
        if self._halt.is_set():
            return ""
        return None

    def lost(self) -> str | None:
        """``"<stream> disconnected: <why>"`` once a device is gone, else ``None``."""
        dead = [p for p in self._pumps if p.error is not None]
        return f"{dead[0].stream} disconnected: {dead[0].error}" if dead else None

    @property
    def halted(self) -> bool:
        """Whether reading is stopping or has stopped."""
        return self._halt.is_set()

    def running(self) -> bool:
        """Whether the acquisition is still reading (no end condition met yet)."""
        return self._started and self.finished() is None

    def request_stop(self, reason: str) -> None:
        """Ask a running :meth:`run` (e.g. in another thread) to stop cleanly with ``reason``."""
        if self._stop_request is None:
            self._stop_request = reason

    def halt(self, reason: str) -> None:
        """Stop reading now (a listener that cannot go on, e.g. a full disk); ``reason``
        becomes the end reason unless another one came first."""
        if self._halt_reason is None:
            self._halt_reason = reason
        self._halt.set()

    def stop(self, reason: str | None = None) -> AcquisitionStats:
        """Stop reading, dispatch what is queued, close the rig, then call every listener's
        ``on_stop``, the lossy ones' first (idempotent).

        :param reason: the end reason recorded when no end condition gave one.
        :returns: the final statistics.
        :raises Exception: the first failure of a listener (of an ``on_stop``, else of a record
            hook), once every listener has been stopped.
        """
        if self._stopped:
            return self.stats
        self._stopped = True
        if not self.stats.end_reason:
            self.stats.end_reason = self.finished() or reason or ""
        self._halt.set()
        for pump in self._pumps:
            pump.join(timeout=5.0)
        if self._dispatcher is not None:
            self._dispatcher.join()
        if self._live_dispatcher is not None:
            self._live_dispatcher.join()
        self.rig.close()
        stats = self.update_stats()
        if not stats.end_reason:
            stats.end_reason = self._stop_request or self._halt_reason or "stopped"
        log.info(
            "acquisition stopped (%s): %s",
            stats.end_reason,
            ", ".join(f"{n} {stream}" for stream, n in stats.counts.items()),
        )
        for stream, dropped in stats.dropped.items():
            if dropped:
                log.warning(
                    "%s: %d records dropped (%d by the queue, the rest by the device)",
                    stream,
                    dropped,
                    stats.queue_dropped.get(stream, 0),
                )
        if stats.live_dropped:
            log.warning(
                "%d records of the trocar and other streams dropped for the live views and "
                "outputs (their queue was full)",
                stats.live_dropped,
            )
        failures = []
        # the lossy listeners first: what they hand the others as they end (the live
        # estimate's last estimates, posted to the file) is still taken
        in_order = sorted(self.listeners, key=lambda listener: not listener.lossy)
        for listener in in_order if self._started else ():
            try:
                listener.on_stop(self)
            except Exception as exc:  # noqa: BLE001 - raised below, after every listener
                failures.append(exc)
        if failures:
            raise failures[0]
        if self.error is not None:
            raise self.error
        return stats

    def __enter__(self) -> Acquisition:
        self.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: Any
    ) -> None:
        self.stop()

    @contextlib.contextmanager
    def _signals_stop(self):
        """While running, Ctrl-C and SIGTERM ask the loop to stop; once stopping, they are
        ignored with a message (only in the main thread, where Python handles signals)."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return

        def on_signal(signum: int, frame: Any) -> None:
            if self._stop_request is None and not self._halt.is_set():
                self._stop_request = (
                    "stopped by operator"
                    if signum == signal.SIGINT
                    else f"stopped by {signal.Signals(signum).name}"
                )
            else:
                print(
                    f"vbfe: finishing {self.what}, please wait (Ctrl-C is ignored until it "
                    "is closed)",
                    file=sys.stderr,
                    flush=True,
                )

        previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    # -- internals ------------------------------------------------------------------------
    def _set_duration(self, duration_s: float) -> None:
        if not duration_s > 0:
            raise SessionError(f"the duration must be positive, got {duration_s} s")
        self._span_limit_ns = int(duration_s * 1e9)

    def update_stats(self) -> AcquisitionStats:
        """The statistics as of now (also kept in ``self.stats``)."""
        s = self.stats
        s.wall_s = time.monotonic() - self._t_start if self._t_start else 0.0
        s.elapsed_s = (self._frame_t_host[1] - self._frame_t_host[0]) / 1e9
        s.first_frame_host_ns = self._frame_t_host[0]
        s.newest_read_host_ns = max(
            (p.last_t_host_ns for p in self._pumps if p.stream == CAMERA), default=0
        )
        devices = dict(self.rig.streams())
        s.queue_dropped = {p.stream: p.dropped for p in self._pumps}
        s.live_skipped, s.live_dropped = self.live_skipped, self._live_dropped
        s.dropped = {p.stream: p.dropped + devices[p.stream].stats.dropped for p in self._pumps}
        return s

    def backlog(self, handed: int = 0) -> float:
        """How full the camera's queue to the dispatch is (0 … 1), counting ``handed`` frames
        taken from it but not yet handled too: how far the listeners of every frame (the
        file's writer) are behind; 0 for a paced camera, which waits."""
        frames = self._queues.get(CAMERA)
        if frames is None or self.paced:
            return 0.0
        return (frames.qsize() + handed) / frames.maxsize

    @property
    def live_skipped(self) -> int:
        """Frames no lossy listener saw: a newer one replaced them before they were taken."""
        return self._live_frames.skipped

    def _offer_live(self, stream: str | None, item: Any) -> None:
        """Hand a record (``stream`` ``None``: a :class:`Gap`) to the lossy listeners' thread;
        never waits."""
        if stream == CAMERA:  # the first frame is pinned: a live run's rest reference
            self._live_frames.put(item, pinned=not self._live_frames.put_count)
            return
        try:
            self._live_records.put_nowait((stream, item))
        except queue.Full:
            self._live_dropped += 1

    def _dispatch_loop(self) -> None:
        try:
            self._dispatch()
        finally:
            self._dispatch_done.set()

    def _dispatch(self) -> None:
        others = [s for s in self._queues if s != CAMERA]
        counts = self.stats.counts
        for stream in [*self._queues, PROJECTOR]:
            counts.setdefault(stream, 0)
        try:
            while True:
                pumps_done = self._halt.is_set() and not any(p.is_alive() for p in self._pumps)
                batches = {}
                if CAMERA in self._queues:
                    batches[CAMERA] = self._within_duration(
                        _drain(self._queues[CAMERA], _FRAME_BATCH, 0.0 if pumps_done else 0.02)
                    )
                elif not pumps_done:
                    time.sleep(0.02)
                for stream in others:
                    items = _drain(self._queues[stream], 1 << 20)
                    if self._end_host_ns is not None:
                        items = [r for r in items if r.t_host_ns < self._end_host_ns]
                    batches[stream] = items
                control = _drain(self._control, 1 << 20)
                for stream, items in batches.items():
                    if items:
                        counts[stream] += len(items)
                        for listener in self._direct:
                            listener.on_records(stream, items)
                for message in control:
                    if isinstance(message, Gap):
                        log.warning(
                            "%s gap (%s): %d records lost after seq %d",
                            message.stream,
                            message.reason,
                            message.count,
                            message.last_seq,
                        )
                        if self._lossy:
                            self._offer_live(None, message)
                    for listener in self._direct:
                        if isinstance(message, Gap):
                            listener.on_gap(message)
                        else:
                            listener.on_records(PROJECTOR, [message])
                    if not isinstance(message, Gap):
                        counts[PROJECTOR] += 1
                for listener in self._direct:
                    listener.on_round()
                if pumps_done and not (control or any(batches.values())):
                    break
        except Exception as exc:  # handed to stop(), which raises it after the listeners stop
            self.error = exc
            self._halt.set()

    def _live_loop(self) -> None:
        """Serve the lossy listeners: the newest frame and what else came, each round, until
        the dispatch has ended and nothing is left; records past the acquisition's end are
        not handed over. A failing hook stops the acquisition as in the dispatch."""
        try:
            while True:
                dispatched = self._dispatch_done.is_set()
                frame = self._live_frames.take(0.0 if dispatched else 0.02)
                items = _drain(self._live_records, 1 << 20)
                end = self._end_host_ns
                batches: dict[str, list[Any]] = {}
                if frame is not None:
                    batches[CAMERA] = [frame]
                gaps = []
                for stream, item in items:
                    if stream is None:
                        gaps.append(item)
                    elif stream == PROJECTOR or end is None or item.t_host_ns < end:
                        batches.setdefault(stream, []).append(item)
                if end is not None and frame is not None and frame.t_host_ns >= end:
                    del batches[CAMERA]
                for stream, records in batches.items():
                    for listener in self._lossy:
                        listener.on_records(stream, records)
                for gap in gaps:
                    for listener in self._lossy:
                        listener.on_gap(gap)
                for listener in self._lossy:
                    listener.on_round()
                if dispatched and frame is None and not items:
                    break
        except Exception as exc:  # handed to stop(), as a dispatch failure is
            if self.error is None:
                self.error = exc
            self._halt.set()

    def _within_duration(self, frames: list[StereoFrame]) -> list[StereoFrame]:
        """The frames that fall inside the requested duration (a faster-than-real-time
        simulation may deliver many frames per progress tick)."""
        if frames and not self._frame_t_host[0]:
            self._frame_t_host[0] = frames[0].t_host_ns
        kept = frames
        if self._span_limit_ns is not None and self._frame_t_host[0]:
            self._end_host_ns = self._frame_t_host[0] + self._span_limit_ns
            kept = [fr for fr in frames if fr.t_host_ns < self._end_host_ns]
            if len(kept) < len(frames):
                self._span_reached.set()
        if kept:
            self._frame_t_host[1] = kept[-1].t_host_ns
        return kept

    def _reached_end_ns(self) -> int | None:
        """The acquisition's end (host ns) once the duration is reached, for other readers."""
        return self._end_host_ns if self._span_reached.is_set() else None
