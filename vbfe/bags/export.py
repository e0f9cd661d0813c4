"""``vbfe export --format mcap``: a session as an MCAP file of ROS 2 messages.

Topics (see :data:`messages.TOPICS`): per eye ``sensor_msgs/CompressedImage``
(``.../compressed``) as ``--images`` says (:mod:`vbfe.messages.images`: PNG, lossless, by default;
JPEG; an ``mjpeg`` session's own JPEG bytes, not encoded again), or ``sensor_msgs/Image``
``bgr8`` with ``raw``;
``sensor_msgs/CameraInfo`` per eye from the stored calibration; ``geometry_msgs/WrenchStamped``
for the trocar; ``sensor_msgs/PointCloud2`` from a clouds sidecar; ``vbfe_msgs`` projector
events, gaps and live estimates (with their prediction interval and out-of-distribution flag
when the session stored them); ``std_msgs/String`` with the session's attributes (JSON) and
its calibration (vbfe YAML, for an exact round trip). Every header stamp and log time is the
synchronized time in Unix nanoseconds (frame times with the verify-sync correction); the
publish time is the host arrival. Written with MCAP's writer (``ros2`` profile, ``ros2msg``
schemas, ``cdr`` messages encoded by rosbags' generated serializers: mcap_ros2's encoder
interprets each message field by field, too slow for 1 kHz force): chunked, compressed and
indexed.
"""

from __future__ import annotations

import contextlib
import heapq
import json
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding, Profile, SchemaEncoding
from mcap.writer import CompressionType, Writer

from vbfe.acquire import SessionReader
from vbfe.common.errors import BagError
from vbfe.common.files import atomic_path
from vbfe.common.version import __version__
from vbfe.messages import builders
from vbfe.messages.builders import header, msg
from vbfe.messages.images import ImageCodec
from vbfe.messages.topics import (
    FRAME_IDS,
    MIN_UNIX_NS,
    TOPICS,
    host_to_unix,
    schema_text,
    typestore,
)

COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4}
_CHUNK_BYTES = 4 << 20
EXPORT_IMAGES = ImageCodec("png")  # lossless


@dataclass
class ExportSummary:
    """What an export wrote: messages per topic and the time range (Unix ns)."""

    path: Path
    messages: dict[str, int]
    start_ns: int
    end_ns: int


def _camera_infos(calibration_yaml: str | None, size: tuple[int, int]) -> dict[str, dict] | None:
    if calibration_yaml is None:
        return None
    from vbfe.calib import Calibration
    from vbfe.calib.export import ros_distortion_model

    cal = Calibration.from_yaml_text(calibration_yaml, source="the session's calibration")
    roi = msg(
        "sensor_msgs/msg/RegionOfInterest",
        x_offset=0,
        y_offset=0,
        height=0,
        width=0,
        do_rectify=False,
    )
    return {
        eye: {
            "height": size[1],
            "width": size[0],
            "distortion_model": ros_distortion_model(D),
            "d": D.astype(np.float64),
            "k": K.ravel(),
            "r": R.ravel(),
            "p": P.ravel(),
            "binning_x": 0,
            "binning_y": 0,
            "roi": roi,
        }
        for eye, K, D, R, P in (
            ("left", cal.K1, cal.D1, cal.R1, cal.P1),
            ("right", cal.K2, cal.D2, cal.R2, cal.P2),
        )
    }


class _Mcap:
    """One MCAP file being written: schemas registered on first use, message counts."""

    def __init__(self, fh: Any, compression: str) -> None:
        self.writer = Writer(fh, chunk_size=_CHUNK_BYTES, compression=COMPRESSIONS[compression])
        self.writer.start(profile=Profile.ROS2, library=f"vbfe {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self.first_ns: int | None = None
        self.last_ns = 0

    def write(
        self, topic: str, msgtype: str, message: Any, t_ns: int, publish_ns: int | None = None
    ) -> None:
        """Add ``message`` (a :func:`msg` object) on ``topic`` at Unix time ``t_ns``."""
        if topic not in self._channels:
            if msgtype not in self._schemas:
                self._schemas[msgtype] = self.writer.register_schema(
                    msgtype, SchemaEncoding.ROS2, schema_text(msgtype).encode()
                )
            self._channels[topic] = self.writer.register_channel(
                topic, MessageEncoding.CDR, self._schemas[msgtype]
            )
        if t_ns < MIN_UNIX_NS:
            raise BagError(
                f"a {topic} message would be stamped {t_ns} ns, before the year "
                "2000: the session's clock pairs do not place it in Unix time"
            )
        self.writer.add_message(
            self._channels[topic],
            log_time=t_ns,
            # the writer takes any buffer (a memoryview here, no copy); it is annotated bytes
            data=typestore().serialize_cdr(message, msgtype),  # type: ignore[arg-type]
            publish_time=publish_ns if publish_ns is not None else t_ns,
            sequence=self.counts.get(topic, 0),
        )
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.first_ns = t_ns if self.first_ns is None else min(self.first_ns, t_ns)
        self.last_ns = max(self.last_ns, t_ns)


class _BackgroundFile:
    """A write-only binary stream whose bytes go to ``fh`` from a background thread, so the
    disk write of one chunk overlaps the building and compression of the next. ``close``
    waits for the last write and re-raises a failed one."""

    def __init__(self, fh: Any) -> None:
        self._fh, self._position = fh, 0
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="export-write")
        self._last: Future | None = None

    def write(self, data: bytes) -> int:
        if self._last is not None and self._last.done():
            self._last.result()  # a failed write stops the export at once
        self._last = self._pool.submit(self._fh.write, bytes(data))
        self._position += len(data)
        return len(data)

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self._pool.shutdown(wait=True)
        if self._last is not None:
            self._last.result()


class _Prefetch:
    """Loads items ``i + 1`` … ``i + depth`` in ``depth`` background threads while item ``i``
    is written, so reading (HDF5 decompression), image encoding and writing (chunk
    compression) overlap."""

    def __init__(self, load: Callable[[int], Any], n: int, depth: int = 1) -> None:
        self._load, self._n, self._depth = load, n, depth
        self._pool = ThreadPoolExecutor(max_workers=depth, thread_name_prefix="export-read")
        self._pending: dict[int, Future] = {}

    def get(self, i: int) -> Any:
        future = self._pending.pop(i, None) or self._pool.submit(self._load, i)
        for j in range(i + 1, min(i + 1 + self._depth, self._n)):
            if j not in self._pending:
                self._pending[j] = self._pool.submit(self._load, j)
        return future.result()

    def close(self) -> None:
        self._pool.shutdown(cancel_futures=True)


def _frame_writer(
    reader: SessionReader,
    out: _Mcap,
    infos: dict[str, dict] | None,
    to_unix: Callable[[Any], Any],
    frames: _Prefetch,
) -> Callable[[int], None]:
    """Writes frame ``i`` (``frames.get(i)``: ``(format, (left, right) bytes)`` or
    ``(None, decoded frame)``)."""
    t_sync = to_unix(reader.frame_times_ns())
    t_arrival = to_unix(reader.stream_times("camera")[1])

    def write(i: int) -> None:
        t, arrival = int(t_sync[i]), int(t_arrival[i])
        image_format, loaded = frames.get(i)
        for k, eye in enumerate(("left", "right")):
            if image_format is not None:
                out.write(
                    TOPICS[f"{eye}_image"] + "/compressed",
                    builders.COMPRESSED_IMAGE,
                    builders.compressed_image(t, eye, image_format, loaded[k]),
                    t,
                    arrival,
                )
            else:
                out.write(
                    TOPICS[f"{eye}_image"],
                    builders.IMAGE,
                    builders.raw_image(t, eye, getattr(loaded, eye)),
                    t,
                    arrival,
                )
            if infos is not None:
                out.write(
                    TOPICS[f"{eye}_info"],
                    "sensor_msgs/msg/CameraInfo",
                    msg(
                        "sensor_msgs/msg/CameraInfo", header=header(t, FRAME_IDS[eye]), **infos[eye]
                    ),
                    t,
                    arrival,
                )

    return write


def _force_writer(
    reader: SessionReader, out: _Mcap, to_unix: Callable[[Any], Any]
) -> Callable[[int], None]:
    t_sync = to_unix(reader.force_times_ns())
    t_arrival = to_unix(reader.stream_times("force")[1])
    forces = reader.forces_n()
    columns = {axis: k for k, axis in enumerate(reader.force_axes)}

    def write(i: int) -> None:
        out.write(
            TOPICS["wrench"],
            builders.WRENCH,
            builders.wrench(
                t_sync[i], {axis: forces[i, k] for axis, k in columns.items() if axis in "xyz"}
            ),
            int(t_sync[i]),
            int(t_arrival[i]),
        )

    return write


def _events(
    reader: SessionReader, to_unix: Callable[[Any], Any]
) -> Iterator[tuple[int, str, str, Any]]:
    """(Unix time, topic, type, message) of the small streams."""
    for e in reader.projector_events():
        t = int(to_unix(e.t_host_ns))
        yield (
            t,
            TOPICS["projector"],
            builders.PROJECTOR_EVENT,
            builders.projector_event(t, e.pattern, e.frame_id, e.seq),
        )
    for gap in reader.gaps():
        t = int(to_unix(gap["t_host_ns"]))
        yield (
            t,
            TOPICS["gaps"],
            "vbfe_msgs/msg/Gap",
            msg(
                "vbfe_msgs/msg/Gap",
                header=header(t, gap["stream"]),
                **{k: gap[k] for k in ("stream", "reason", "last_seq", "next_seq", "count")},
            ),
        )
    estimates = reader.estimates()
    if estimates is not None and len(estimates):
        target = str(estimates.attrs.get("target", ""))
        axes = {"magnitude": ["|F|"], "xyz": ["x", "y", "z"]}.get(target, [target])
        if len(axes) != estimates.force_n.shape[1]:
            axes = [f"f{k}" for k in range(estimates.force_n.shape[1])]
        none = np.zeros((len(estimates), 0))  # no interval stored: empty per message
        bounds = {
            name: np.asarray(
                getattr(estimates, name) if getattr(estimates, name) is not None else none,
                np.float64,
            )
            for name in ("lo_n", "hi_n")
        }
        for k in range(len(estimates)):
            t = int(to_unix(estimates.t_frame_host_ns[k]))
            yield (
                t,
                TOPICS["estimate"],
                "vbfe_msgs/msg/ForceEstimate",
                msg(
                    "vbfe_msgs/msg/ForceEstimate",
                    header=header(t, FRAME_IDS["trocar"]),
                    target=target,
                    axes=axes,
                    force_n=estimates.force_n[k].astype(np.float64),
                    lo_n=bounds["lo_n"][k],
                    hi_n=bounds["hi_n"][k],
                    ood=bool(estimates.ood[k]) if estimates.ood is not None else False,
                    frame_seq=int(estimates.frame_seq[k]),
                    latency_s=float(estimates.latency_s[k]),
                ),
            )


def _load_frame(reader: SessionReader, images: ImageCodec, i: int) -> tuple[str | None, Any]:
    """Frame ``i`` as :func:`_frame_writer` takes it: an ``mjpeg`` session's own JPEG pair
    unless ``raw`` is asked for, else encoded by ``images`` (or decoded for ``raw``)."""
    if reader.encoding == "jpeg" and images.compressed:
        return "jpeg", reader.encoded_frame(i)
    frame = reader.frame(i)
    if not images.compressed:
        return None, frame
    return images.kind, (images.encode(frame.left), images.encode(frame.right))


def _cloud_writer(
    clouds: Any, t_unix: np.ndarray, reader: SessionReader, out: _Mcap
) -> Callable[[int], None]:
    """Writes frame ``i`` of an open :class:`~vbfe.recon.clouds.CloudReader` as PointCloud2."""
    if clouds.n_frames != reader.n_frames:
        raise BagError(
            f"{clouds.path} has {clouds.n_frames} frames, the session "
            f"{reader.n_frames}: it belongs to another session (or an older one); "
            "run `vbfe reconstruct` again"
        )

    def write(i: int) -> None:
        points, colors = clouds.cloud(i)
        t = int(t_unix[i])
        out.write(
            TOPICS["points"], builders.POINT_CLOUD, builders.point_cloud(t, points, colors), t
        )

    return write


def export_mcap(
    session_path: str | Path,
    out_path: str | Path,
    clouds_path: str | Path | None = None,
    compression: str = "lz4",
    on_progress: Callable[[int, int], None] | None = None,
    images: ImageCodec = EXPORT_IMAGES,
) -> ExportSummary:
    """Write the session (and optionally its clouds) to ``out_path`` as MCAP, in time order,
    under a temporary name renamed when complete, its images as ``images`` says.
    ``on_progress(done, total)`` per frame."""
    if compression not in COMPRESSIONS:
        raise BagError(f"unknown MCAP compression {compression!r}; use zstd or lz4")
    out_path = Path(out_path)
    with atomic_path(out_path) as tmp, SessionReader(session_path) as reader:
        attrs = reader.attrs
        ref = host_to_unix(
            reader.clock_pairs(), attrs.get("start_utc_ns"), attrs.get("start_host_ns")
        )
        if ref is None:
            raise BagError(
                f"{session_path} has no clock pairs and no start time: its host "
                "times cannot be placed in Unix time"
            )
        host_ref, utc_ref = ref

        def to_unix(t_host: Any) -> Any:
            return np.asarray(t_host, np.int64) - host_ref + utc_ref

        infos = _camera_infos(reader.calibration_yaml(), reader.frame_size)
        with open(tmp, "wb") as fh:
            stream = _BackgroundFile(fh)
            try:
                out = _Mcap(stream, compression)
                summary = _write_all(reader, out, infos, to_unix, clouds_path, on_progress, images)
                out.writer.finish()
            finally:
                stream.close()
    return ExportSummary(out_path, summary.counts, summary.first_ns or 0, summary.last_ns)


def _write_all(
    reader: SessionReader,
    out: _Mcap,
    infos: dict[str, dict] | None,
    to_unix: Callable[[Any], Any],
    clouds_path: str | Path | None,
    on_progress: Callable[[int, int], None] | None,
    images: ImageCodec,
) -> _Mcap:
    n = reader.n_frames
    frame_t = to_unix(reader.frame_times_ns())
    force_t = to_unix(reader.force_times_ns())
    first = min(
        [int(t[0]) for t in (frame_t, force_t) if len(t)]
        or [int(to_unix(reader.attrs.get("start_host_ns", 0)))]
    )
    session = {
        "attrs": {k: v for k, v in reader.attrs.items() if k != "metadata_json"},
        "metadata": reader.metadata,
        "force_axes": reader.force_axes,
        "analysis": reader.analysis(),
        "frame_size": list(reader.frame_size),
        "encoding": reader.encoding,
    }
    string = "std_msgs/msg/String"
    out.write(TOPICS["session"], string, msg(string, data=json.dumps(session, default=str)), first)
    yaml_text = reader.calibration_yaml()
    if yaml_text is not None:
        out.write(TOPICS["calibration"], string, msg(string, data=yaml_text), first)
    write_force = _force_writer(reader, out, to_unix)
    with contextlib.ExitStack() as stack:
        encoding = images.compressed and reader.encoding != "jpeg"  # OpenCV encodes in parallel
        prefetch = _Prefetch(
            partial(_load_frame, reader, images), n, min(2, os.cpu_count() or 1) if encoding else 1
        )
        stack.callback(prefetch.close)
        write_frame = _frame_writer(reader, out, infos, to_unix, prefetch)

        def frame(i: int) -> None:
            write_frame(i)
            if on_progress is not None:
                on_progress(i + 1, n)

        # (Unix time, stream rank, write) per message, each stream in time order
        streams: list[Iterator[tuple[int, int, Callable[[], None]]]] = [
            ((int(frame_t[i]), 0, partial(frame, i)) for i in range(n)),
            ((int(force_t[i]), 1, partial(write_force, i)) for i in range(len(force_t))),
            (
                (t, 2, partial(out.write, topic, typ, msg, t))
                for t, topic, typ, msg in sorted(_events(reader, to_unix), key=lambda e: e[0])
            ),
        ]
        if clouds_path is not None:
            from vbfe.recon import CloudReader

            clouds = stack.enter_context(CloudReader(clouds_path))
            cloud_t = to_unix(clouds.frame_table("t_host_ns"))
            write_cloud = _cloud_writer(clouds, cloud_t, reader, out)
            streams.append(
                (int(cloud_t[i]), 3, partial(write_cloud, i)) for i in range(len(cloud_t))
            )
        for _, _, write in heapq.merge(*streams, key=lambda item: item[:2]):
            write()
    return out
