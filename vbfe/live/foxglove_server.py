"""``--foxglove [PORT]``: the running rig served to Foxglove over its WebSocket protocol
(foxglove-sdk), as one more listener of the acquisition.

Topics and schemas are the MCAP export's (:data:`vbfe.messages.topics.TOPICS`, ROS 2 messages in
CDR, which Foxglove reads without plugins): both eyes' images as
``sensor_msgs/CompressedImage`` (``--images``: JPEG 90 by default, PNG, or raw
``sensor_msgs/Image``) at most ``image_hz`` frames a second, the trocar's
``geometry_msgs/WrenchStamped``, the projector's ``vbfe_msgs/ProjectorEvent``, the point cloud
as ``sensor_msgs/PointCloud2`` at most ``cloud_hz`` times a second; the live estimate as JSON
on ``/vbfe/estimate`` with every field of the estimate record (a JSON schema made from the
record's fields: what the estimator adds flows through); each extra stream as JSON on
``/vbfe/streams/<name>``. Stamps are Unix time (the host clock mapped at start).

Nothing here slows the recording: the listener hooks only hand records over, the newest frame
and cloud through one-slot mailboxes (a frame not yet sent is replaced, counted in
``frames_skipped``), the small records through a bounded queue (full: dropped, counted in
``records_dropped``); one thread of its own encodes and sends, and only while a client
subscribes. The server binds to 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from foxglove.websocket import ChannelView, Client, ServerListener

from vbfe.acquire import Recorder
from vbfe.common.errors import LiveError
from vbfe.common.mailbox import Mailbox
from vbfe.common.priority import yield_to_recording
from vbfe.drivers import ForceSample, ProjectorEvent, StereoFrame
from vbfe.live.foxglove_overflow import Overflows
from vbfe.live.outputs import EstimateOutput
from vbfe.messages import builders
from vbfe.messages.images import ImageCodec
from vbfe.messages.topics import TOPICS, schema_text

if TYPE_CHECKING:
    from vbfe.acquire import Acquisition
    from vbfe.live.estimator import LiveEstimate

log = logging.getLogger(__name__)

LIVE_IMAGES = ImageCodec("jpeg", 90)
STREAM_TOPIC = "/vbfe/streams/"  # + the stream's name
_QUEUE_RECORDS = 8192  # small records waiting for the sender (8 s of a 1 kHz trocar)
_POLL_S = 0.02


def _json_value(value: Any) -> Any:
    """A record field as JSON: arrays and tuples as lists, NaN as null."""
    if isinstance(value, np.ndarray | tuple | list):
        return [_json_value(v) for v in np.asarray(value).tolist()]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _json_type(annotation: str) -> dict[str, Any]:
    """The JSON schema of a record field from its type annotation, in the types the Foxglove
    app reads (its ``parseJsonSchema``: one type per field, never ``"null"``): numbers,
    integers, strings, booleans, arrays of numbers. A NaN (or ``None``) goes out as ``null``
    all the same: the app's decoder passes any JSON value through.

    :raises TypeError: for an annotation of another type (a field the app could not plot)."""
    kinds = {"int": "integer", "float": "number", "str": "string", "bool": "boolean"}
    parts = [p.strip() for p in annotation.split("|") if p.strip() != "None"]
    if len(parts) == 1 and any(k in parts[0] for k in ("ndarray", "tuple", "list", "Sequence")):
        return {"type": "array", "items": {"type": "number"}}
    if len(parts) == 1 and parts[0] in kinds:
        return {"type": kinds[parts[0]]}
    raise TypeError(f"no JSON schema type the Foxglove app reads for {annotation!r}")


def estimate_schema() -> dict[str, Any]:
    """The JSON schema of ``/vbfe/estimate``: every field of :class:`LiveEstimate` (read from
    the record itself), its ``latency_s``, and ``target``."""
    from vbfe.live.estimator import LiveEstimate

    properties = {f.name: _json_type(str(f.type)) for f in dataclasses.fields(LiveEstimate)}
    properties["latency_s"] = {"type": "number"}
    properties["target"] = {"type": "string"}
    return {"title": "vbfe.LiveEstimate", "type": "object", "properties": properties}


def estimate_json(estimate: LiveEstimate, target: str) -> dict[str, Any]:
    """One estimate as the JSON message of ``/vbfe/estimate`` (every field of the record)."""
    out = {f.name: _json_value(getattr(estimate, f.name)) for f in dataclasses.fields(estimate)}
    out["latency_s"] = estimate.latency_s
    out["target"] = target
    return out


BACKLOG = 1024  # foxglove-sdk's queue of messages per client (its message_backlog_size)
STOP_WAIT_S = 2.0  # the longest wait at the end for the clients to take what is queued


class _Subscribers(ServerListener):
    """Which client subscribes to which channel (foxglove-sdk's ``ServerListener`` callbacks,
    on its threads), and how many messages were handed over for each client."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._by_channel: dict[int, set[int]] = {}
        self.handed: dict[int, int] = {}  # by client id, in the order they subscribed

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            self._by_channel.setdefault(channel.id, set()).add(client.id)
            self.handed.setdefault(client.id, 0)

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            self._by_channel.get(channel.id, set()).discard(client.id)

    def count(self, channel_id: int) -> None:
        """One message logged on the channel: one more for each of its subscribers."""
        with self._lock:
            for client in self._by_channel.get(channel_id, ()):
                self.handed[client] += 1


class FoxgloveServer(EstimateOutput):
    """A Foxglove WebSocket server on ``host:port`` (0: a free port; :attr:`port` says which
    once started) while the rig runs; images as ``images`` says, at most ``image_hz`` frames
    a second (a viewer needs no more; each costs two encodings); the point cloud at most
    ``cloud_hz`` a second; ``target`` names the estimate's model target (a live run's; none:
    no estimate or cloud channel); ``on_ready`` hears the ``ws://`` address once it listens.

    :raises LiveError: by :meth:`open` (or at start), when the port cannot be opened.
    """

    def __init__(
        self,
        port: int,
        images: ImageCodec = LIVE_IMAGES,
        host: str = "127.0.0.1",
        target: str = "",
        image_hz: float = 10.0,
        cloud_hz: float = 2.0,
        on_ready: Callable[[str], None] | None = None,
    ) -> None:
        self.on_ready = on_ready  # told the server's ws:// address once it listens
        self.host, self.port, self.images, self.target = host, port, images, target
        self.image_interval_ns = int(1e9 / image_hz)
        self.cloud_interval_ns = int(1e9 / cloud_hz)
        self.frames_skipped = self.records_dropped = 0
        self.error: str | None = None  # why the sending thread stopped early
        self.stalled = False  # a client was still not reading when the server closed
        self.sent: dict[str, int] = {}  # messages sent per topic
        self._frames: Mailbox[StereoFrame] = Mailbox()
        self._clouds: Mailbox[tuple[int, np.ndarray, np.ndarray]] = Mailbox()
        self._records: queue.Queue[tuple[str, Any]] = queue.Queue(_QUEUE_RECORDS)
        self._last_cloud_ns = self._last_frame_ns = 0
        self._to_unix_ns = 0
        self._halt = threading.Event()
        self._thread: threading.Thread | None = None
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[str, Any] = {}
        self._subscribers = _Subscribers()
        self._overflows = Overflows()
        self._stream_labels: dict[str, tuple[str, ...]] = {}
        self._beside_recording = False

    # -- lifecycle --------------------------------------------------------------------------
    def open(self) -> None:
        """Start listening (done by :meth:`on_start` unless done before: open it before the
        acquisition starts to refuse a busy port before anything is recorded).

        :raises LiveError: when the port cannot be opened."""
        import foxglove

        if self._server is not None:
            return
        self._context = foxglove.Context()
        self._overflows.attach()
        try:
            self._server = foxglove.start_server(
                name="vbfe",
                host=self.host,
                port=self.port,
                context=self._context,
                server_listener=self._subscribers,
                message_backlog_size=BACKLOG,
            )
        except Exception as exc:  # noqa: BLE001 - the SDK's own error types vary by version
            self._overflows.detach()
            raise LiveError(
                f"--foxglove {self.port}: cannot serve on {self.host}:{self.port} ({exc}); "
                "give another port"
            ) from None
        self.port = int(self._server.port)

    def on_start(self, acquisition: Acquisition) -> None:
        """Open the server (unless open) and its channels; start the sending thread."""
        import foxglove

        self.open()
        self._beside_recording = isinstance(acquisition, Recorder)
        self._to_unix_ns = time.time_ns() - time.monotonic_ns()
        image_type = builders.COMPRESSED_IMAGE if self.images.compressed else builders.IMAGE
        suffix = "/compressed" if self.images.compressed else ""
        for eye in ("left", "right"):
            self._ros_channel(TOPICS[f"{eye}_image"] + suffix, image_type)
        self._ros_channel(TOPICS["wrench"], builders.WRENCH)
        self._ros_channel(TOPICS["projector"], builders.PROJECTOR_EVENT)
        if self.target:
            self._ros_channel(TOPICS["points"], builders.POINT_CLOUD)
        if self.target:
            self._channels[TOPICS["estimate"]] = foxglove.Channel(
                TOPICS["estimate"], schema=estimate_schema(), context=self._context
            )
        for name, device in acquisition.rig.streams():
            info = getattr(device, "info", None)
            if name in ("camera", "force", "projector") or info is None:
                continue
            self._stream_labels[name] = info.channels
            fields: dict[str, dict[str, Any]] = (
                {"text": {"type": "string"}}
                if info.markers
                else {label: {"type": "number"} for label in info.channels}
            )
            fields["t_device_ns"] = {"type": "integer"}
            self._channels[STREAM_TOPIC + name] = foxglove.Channel(
                STREAM_TOPIC + name,
                schema={"title": f"vbfe.stream.{name}", "type": "object", "properties": fields},
                context=self._context,
            )
        self._thread = threading.Thread(target=self._run, name="vbfe-foxglove", daemon=True)
        self._thread.start()
        if self.on_ready is not None:
            self.on_ready(f"ws://{self.host}:{self.port}")

    def _ros_channel(self, topic: str, msgtype: str) -> None:
        import foxglove

        schema = foxglove.Schema(
            name=msgtype, encoding="ros2msg", data=schema_text(msgtype).encode()
        )
        self._channels[topic] = foxglove.Channel(
            topic, schema=schema, message_encoding="cdr", context=self._context
        )

    def on_stop(self, acquisition: Acquisition) -> None:
        """Stop sending and close the server: foxglove-sdk's ``stop`` waits for every client
        to take what is queued for it, forever for one that stopped reading, so it is waited
        for ``STOP_WAIT_S`` at most (then left to end with the process; ``stalled`` set)."""
        self._halt.set()
        if self._thread is not None:
            self._thread.join()
        if self._server is not None:
            stopping = threading.Thread(target=self._server.stop, name="vbfe-fox-stop", daemon=True)
            stopping.start()
            stopping.join(STOP_WAIT_S)
            self.stalled = stopping.is_alive()
            self._server = None
            self._overflows.detach()
        self.frames_skipped = self._frames.skipped

    # -- listener hooks: hand over, never wait ----------------------------------------------
    def _hand(self, kind: str, item: Any) -> None:
        try:
            self._records.put_nowait((kind, item))
        except queue.Full:
            self.records_dropped += 1

    def on_records(self, stream: str, records: Sequence[Any]) -> None:
        if stream in self._stream_labels:
            self._hand("stream", (stream, records))
        else:
            super().on_records(stream, records)

    def on_frames(self, frames: Sequence[StereoFrame]) -> None:
        if frames and frames[-1].t_host_ns - self._last_frame_ns >= self.image_interval_ns:
            self._last_frame_ns = frames[-1].t_host_ns
            self._frames.put(frames[-1])

    def on_samples(self, samples: Sequence[ForceSample]) -> None:
        self._hand("force", samples)

    def on_events(self, events: Sequence[ProjectorEvent]) -> None:
        self._hand("projector", events)

    def on_estimate(self, estimate: LiveEstimate) -> None:
        self._hand("estimate", estimate)

    def on_cloud(self, t_host_ns: int, points: np.ndarray, colors: np.ndarray) -> None:
        if t_host_ns - self._last_cloud_ns >= self.cloud_interval_ns:
            self._last_cloud_ns = t_host_ns
            self._clouds.put((t_host_ns, points, colors))

    # -- the sending thread -----------------------------------------------------------------
    def _run(self) -> None:
        """Send until stopped; a failure stops the viewer only (kept in ``error``), never the
        acquisition (a viewer: beside a recording at a lower priority than it)."""
        if self._beside_recording:
            yield_to_recording()
        try:
            self._send_all()
        except Exception as exc:  # noqa: BLE001 - reported by the command, not raised
            self.error = f"{type(exc).__name__}: {exc}"

    def _send_all(self) -> None:
        while not self._halt.is_set():
            self._tell_overflows()
            frame = self._frames.take(_POLL_S)
            if frame is not None:
                self._send_frame(frame)
            cloud = self._clouds.take(0.0)
            if cloud is not None and self._channels[TOPICS["points"]].has_sinks():
                t = cloud[0] + self._to_unix_ns
                self._send(
                    TOPICS["points"], builders.POINT_CLOUD, t, builders.point_cloud(t, *cloud[1:])
                )
            while True:
                try:
                    kind, item = self._records.get_nowait()
                except queue.Empty:
                    break
                self._send_record(kind, item)

    def _tell_overflows(self) -> None:
        """A client foxglove-sdk reports fallen behind: said in the log and, as a warning,
        in every client's status (the Foxglove app shows it under its problems)."""
        from foxglove.websocket import StatusLevel

        for client in self._overflows.new():
            text = (
                f"Foxglove client {client} fell behind: its queue of {BACKLOG} messages is "
                "full and the oldest are dropped for it (the recording loses nothing)"
            )
            log.warning(text)
            if self._server is not None:
                self._server.publish_status(text, StatusLevel.Warning, id="vbfe-fell-behind")

    def _log(self, topic: str, t_ns: int, data: Any) -> None:
        channel = self._channels[topic]
        channel.log(data, log_time=int(t_ns))
        self.sent[topic] = self.sent.get(topic, 0) + 1
        self._subscribers.count(channel.id())

    def summary(self, recording: bool = False) -> str:
        """The closing line: messages sent, each client's share, what was skipped or dropped
        for the viewer (``recording``: none for the file). foxglove-sdk queues at most
        ``BACKLOG`` messages per client and drops the oldest for one that reads slower,
        without telling how many: a client's share is what it was handed, not what it got.
        The SDK starts sending on a channel before it tells of the subscription (its
        ``on_subscribe`` callback waits for Python's lock), so the messages logged in between
        reach the client uncounted: a share may fall a few short of what was handed."""
        clients = self._subscribers.handed
        per_client = (
            " (" + ", ".join(f"client {c}: {n}" for c, n in clients.items()) + ")"
            if clients
            else ""
        )
        return (
            f"Foxglove: sent {sum(self.sent.values())} messages{per_client}; a client that "
            f"reads slower loses the oldest beyond {BACKLOG} queued (foxglove-sdk does not "
            f"count them); {self.frames_skipped} frames skipped for the viewer"
            + (" (none for the file)" if recording else "")
            + f", {self.records_dropped} records dropped for the viewer"
            + (
                "; fell behind (queue full, oldest dropped): " + ", ".join(self._overflows.clients)
                if self._overflows.clients
                else ""
            )
            + ("; a client that stopped reading was left behind at the end" if self.stalled else "")
        )

    def _send(self, topic: str, msgtype: str, t_ns: int, message: Any) -> None:
        self._log(topic, t_ns, builders.cdr(message, msgtype))

    def _send_frame(self, frame: StereoFrame) -> None:
        suffix = "/compressed" if self.images.compressed else ""
        topics = {eye: TOPICS[f"{eye}_image"] + suffix for eye in ("left", "right")}
        if not any(self._channels[t].has_sinks() for t in topics.values()):
            return
        t = frame.t_host_ns + self._to_unix_ns
        for eye, topic in topics.items():
            image = getattr(frame, eye)
            if self.images.compressed:
                message = builders.compressed_image(
                    t, eye, self.images.kind, self.images.encode(image)
                )
                self._send(topic, builders.COMPRESSED_IMAGE, t, message)
            else:
                self._send(topic, builders.IMAGE, t, builders.raw_image(t, eye, image))

    def _send_record(self, kind: str, item: Any) -> None:
        if kind == "force":
            if self._channels[TOPICS["wrench"]].has_sinks():
                t = np.array([s.t_host_ns for s in item], np.int64) + self._to_unix_ns
                forces = np.zeros((len(item), 3))
                for k, sample in enumerate(item):
                    force = np.asarray(sample.force_n, np.float64)[:3]
                    forces[k, : len(force)] = force
                for t_ns, data in zip(t, builders.wrench_cdr(t, forces), strict=True):
                    self._log(TOPICS["wrench"], int(t_ns), data)
        elif kind == "projector":
            for e in item:
                t = e.t_host_ns + self._to_unix_ns
                message = builders.projector_event(t, e.pattern, e.frame_id, e.seq)
                self._send(TOPICS["projector"], builders.PROJECTOR_EVENT, t, message)
        elif kind == "estimate":
            t = item.t_frame_host_ns + self._to_unix_ns
            self._log(TOPICS["estimate"], t, json.dumps(estimate_json(item, self.target)))
        else:
            name, records = item
            topic, labels = STREAM_TOPIC + name, self._stream_labels[name]
            if not self._channels[topic].has_sinks():
                return
            for r in records:
                fields: dict[str, Any] = (
                    {"text": r.text}
                    if r.text is not None
                    else dict(zip(labels, _json_value(r.values), strict=False))
                )
                fields["t_device_ns"] = r.t_device_ns
                self._log(topic, r.t_host_ns + self._to_unix_ns, json.dumps(fields))
