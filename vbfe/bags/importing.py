"""``vbfe import bag``: a robot's bag (MCAP, rosbag2 folder or ROS 1 ``.bag``, read through
rosbags) as a vbfe session that ``calibrate``, ``reconstruct`` and ``train`` take.

Stereo images come from two topics (paired by header stamp) or one side-by-side topic, raw
(``sensor_msgs/Image``) or compressed (``CompressedImage``: JPEG pairs are stored as they are,
in an ``mjpeg`` session); force from a ``WrenchStamped``, ``Wrench`` or ``Vector3Stamped``
topic; the calibration from vbfe's own ``/vbfe/calibration`` (an exported session) or else the
two eyes' ``camera_info``. Message times are the header stamps (the bag's receive time where a
stamp is not a Unix time), placed on the session's host clock 1000 s after the bag's first
message, with clock pairs that map them back to Unix time.
"""

from __future__ import annotations

import contextlib
import json
import struct
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Rosbag1ReaderError
from rosbags.rosbag2 import ReaderError as Rosbag2ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from vbfe.acquire import SessionWriter, finalize_session
from vbfe.acquire.session.layout import DEFAULT_COMPRESSION
from vbfe.common.errors import BagError
from vbfe.common.files import atomic_path
from vbfe.drivers.samples import ForceSample, JpegStereoFrame, ProjectorEvent, StereoFrame
from vbfe.messages.topics import MIN_UNIX_NS, TOPICS, stamp_ns

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
FORCE_TYPES = (
    "geometry_msgs/msg/WrenchStamped",
    "geometry_msgs/msg/Wrench",
    "geometry_msgs/msg/Vector3Stamped",
)
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
_READ_ERRORS = (AnyReaderError, Rosbag1ReaderError, Rosbag2ReaderError, SerdeError)
# what rosbags and its decompressors raise on damaged data met while reading messages
_DAMAGED = (*_READ_ERRORS, RuntimeError, OSError, EOFError, struct.error, ValueError)
_HOST_START_NS = 10**12  # the bag's first message sits at this host time (1000 s)
_FLUSH_FRAMES = 64
_CHANNELS = {
    "bgr8": (3, None),
    "rgb8": (3, cv2.COLOR_RGB2BGR),
    "mono8": (1, cv2.COLOR_GRAY2BGR),
    "8UC1": (1, cv2.COLOR_GRAY2BGR),
    "8UC3": (3, None),
    "bgra8": (4, cv2.COLOR_BGRA2BGR),
    "rgba8": (4, cv2.COLOR_RGBA2BGR),
}


@dataclass
class TopicChoice:
    """Which bag topics become which session stream (``image`` with ``side_by_side``, or
    ``left`` and ``right``)."""

    left: str | None = None
    right: str | None = None
    image: str | None = None
    force: str | None = None
    left_info: str | None = None
    right_info: str | None = None
    pair_tolerance_s: float = 0.005


@dataclass
class ImportSummary:
    """What an import wrote."""

    path: Path
    frames: int
    forces: int
    unpaired_images: int
    calibration: str  # "vbfe", "camera_info" or "none: <why>"
    topics: dict[str, str] = field(default_factory=dict)


@contextlib.contextmanager
def open_bag(path: str | Path) -> Iterator[AnyReader]:
    """An open rosbags reader of an MCAP file, rosbag2 folder or ROS 1 bag (context)."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag {path} does not exist")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (*_READ_ERRORS, OSError, ValueError, KeyError) as exc:
        raise BagError(
            f"{path} cannot be read as an MCAP file, rosbag2 folder or ROS 1 bag: "
            f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
        ) from None
    try:
        yield reader
    finally:
        reader.close()


def topic_types(reader: AnyReader) -> dict[str, str]:
    """Topic → message type of an open bag."""
    return {c.topic: c.msgtype for c in reader.connections}


def _listing(topics: dict[str, str], types: tuple[str, ...]) -> str:
    found = [f"{t} ({m.rsplit('/', 1)[-1]})" for t, m in sorted(topics.items()) if m in types]
    return ", ".join(found) or "none"


def _info_topic(image_topic: str, topics: dict[str, str]) -> str | None:
    """``/ns/image_raw[/compressed]`` → ``/ns/camera_info`` when the bag has it."""
    base = image_topic.removesuffix("/compressed").rsplit("/", 1)[0]
    candidate = f"{base}/camera_info"
    return candidate if topics.get(candidate) == INFO_TYPE else None


def choose_topics(topics: dict[str, str], given: TopicChoice) -> TopicChoice:
    """Fill in what was not given from the bag's topics; an ambiguous or missing choice is a
    :class:`BagError` listing the candidates and the flag to pass."""
    choice = TopicChoice(**vars(given))
    for flag, topic in (
        ("--left", choice.left),
        ("--right", choice.right),
        ("--image", choice.image),
        ("--force", choice.force),
        ("--left-info", choice.left_info),
        ("--right-info", choice.right_info),
    ):
        if topic is not None and topic not in topics:
            raise BagError(
                f"{flag} {topic}: no such topic; the bag has "
                f"{', '.join(sorted(topics)) or 'no topics'}"
            )
    images = sorted(t for t, m in topics.items() if m in IMAGE_TYPES)
    if not images:
        raise BagError(
            "the bag has no image topics (sensor_msgs/Image or CompressedImage); "
            f"its topics: {_listing(topics, tuple(topics.values()))}"
        )
    if choice.image is None and (choice.left is None or choice.right is None):
        lefts = [t for t in images if "left" in t.lower() and t != choice.right]
        rights = [t for t in images if "right" in t.lower() and t != choice.left]
        choice.left = choice.left or (lefts[0] if len(lefts) == 1 else None)
        choice.right = choice.right or (rights[0] if len(rights) == 1 else None)
        if choice.left is None or choice.right is None:
            raise BagError(
                f"cannot tell the stereo image topics apart; image topics: "
                f"{_listing(topics, IMAGE_TYPES)}; pass --left and --right, or "
                "--image for one side-by-side topic"
            )
    forces = sorted(t for t, m in topics.items() if m in FORCE_TYPES)
    if choice.force is None:
        if len(forces) != 1:
            raise BagError(
                f"{'several' if forces else 'no'} force topics; candidates: "
                f"{_listing(topics, FORCE_TYPES)}; pass --force TOPIC"
            )
        choice.force = forces[0]
    if topics[choice.force] not in FORCE_TYPES:
        raise BagError(
            f"--force {choice.force} is {topics[choice.force]}, not one of {', '.join(FORCE_TYPES)}"
        )
    for topic in (choice.left, choice.right, choice.image):
        if topic is not None and topics[topic] not in IMAGE_TYPES:
            raise BagError(f"{topic} is {topics[topic]}, not an image topic")
    if choice.image is None and choice.left is not None and choice.right is not None:
        choice.left_info = choice.left_info or _info_topic(choice.left, topics)
        choice.right_info = choice.right_info or _info_topic(choice.right, topics)
    return choice


def _decode(msg: Any, topic: str) -> np.ndarray:
    """A BGR uint8 image from an Image or CompressedImage message."""
    if hasattr(msg, "format"):
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise BagError(f"{topic}: a {msg.format!r} CompressedImage does not decode")
        return image
    if msg.encoding not in _CHANNELS:
        raise BagError(
            f"{topic}: image encoding {msg.encoding!r} is not supported (use "
            f"{', '.join(_CHANNELS)})"
        )
    channels, conversion = _CHANNELS[msg.encoding]
    rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)
    image = rows[:, : msg.width * channels].reshape(msg.height, msg.width, channels)
    return cv2.cvtColor(image, conversion) if conversion is not None else image.copy()


def _is_jpeg(msg: Any) -> bool:
    return hasattr(msg, "format") and ("jpeg" in msg.format.lower() or "jpg" in msg.format.lower())


def _field(msg: Any, name: str) -> Any:
    """A camera_info field under its ROS 2 (``k``) or ROS 1 (``K``) name."""
    return getattr(msg, name, None) if hasattr(msg, name) else getattr(msg, name.upper())


def calibration_from_camera_info(left: Any, right: Any) -> str:
    """vbfe calibration YAML from the two eyes' rectified ``camera_info`` (K, D, R, P): the
    stereo rotation ``R = R2ᵀ R1`` and translation ``T = R2ᵀ (P2[0,3] / P2[0,0], 0, 0)``."""
    from vbfe.calib.calibration import Calibration, reprojection_matrix

    K1, K2 = (np.asarray(_field(m, "k"), float).reshape(3, 3) for m in (left, right))
    R1, R2 = (np.asarray(_field(m, "r"), float).reshape(3, 3) for m in (left, right))
    P1, P2 = (np.asarray(_field(m, "p"), float).reshape(3, 4) for m in (left, right))
    D1, D2 = (np.asarray(_field(m, "d"), float) for m in (left, right))
    if P2[0, 3] == 0 or P2[0, 0] <= 0:
        raise BagError(
            "the right camera_info has no stereo baseline (P[0,3] = 0): it is not "
            "a rectified stereo calibration"
        )
    tx = P2[0, 3] / P2[0, 0]
    calibration = Calibration(
        K1=K1,
        D1=D1,
        K2=K2,
        D2=D2,
        R=R2.T @ R1,
        T=R2.T @ np.array([tx, 0.0, 0.0]),
        R1=R1,
        R2=R2,
        P1=P1,
        P2=P2,
        Q=reprojection_matrix(P1, P2),
        image_size=(int(left.width), int(left.height)),
        info={"source": "ROS camera_info"},
    )
    return calibration.to_yaml_text()


def _time_ns(msg: Any, bag_ns: int) -> int:
    """The header stamp in Unix ns, else the bag's receive time."""
    header = getattr(msg, "header", None)
    t = stamp_ns(header.stamp) if header is not None else 0
    return t if t >= MIN_UNIX_NS else bag_ns


class _Pairer:
    """Pairs left and right images in stamp order within a tolerance; counts the unpaired."""

    def __init__(self, tolerance_ns: int) -> None:
        self.tolerance_ns = tolerance_ns
        self.queues: dict[str, deque] = {"left": deque(), "right": deque()}
        self.unpaired = 0

    def add(self, eye: str, t_ns: int, msg: Any) -> Iterator[tuple[int, Any, Any]]:
        self.queues[eye].append((t_ns, msg))
        left, right = self.queues["left"], self.queues["right"]
        while left and right:
            (tl, ml), (tr, mr) = left[0], right[0]
            if abs(tl - tr) <= self.tolerance_ns:
                left.popleft(), right.popleft()
                yield min(tl, tr), ml, mr
            else:
                (left if tl < tr else right).popleft()
                self.unpaired += 1


class _SessionSink:
    """Writes paired frames and force samples through :class:`SessionWriter`, created at the
    first frame (its size and storage known then)."""

    def __init__(self, out: Path, metadata: dict[str, Any], calibration_yaml: str | None) -> None:
        self.out, self.metadata = out, metadata
        self.calibration_yaml = calibration_yaml
        self.unpaired = 0
        self.writer: SessionWriter | None = None
        self.base_ns: int | None = None
        self.frames = self.forces = 0
        self.pending_forces: list[ForceSample] = []
        self.pending_events: list[ProjectorEvent] = []
        self.last_ns = 0

    def host(self, t_ns: int) -> int:
        assert self.base_ns is not None  # set by the first message
        return t_ns - self.base_ns + _HOST_START_NS

    def clock_pair(self) -> tuple[int, int]:
        return self.last_ns, self.host(self.last_ns)

    def frame(self, t_ns: int, left: Any, right: Any, topics: tuple[Any, Any]) -> None:
        host = self.host(t_ns)
        if _is_jpeg(left) and _is_jpeg(right):
            frame: StereoFrame = JpegStereoFrame(
                (bytes(left.data), bytes(right.data)), self.frames, host, host
            )
            compression = "mjpeg"
        else:
            frame = StereoFrame(
                _decode(left, topics[0]), _decode(right, topics[1]), self.frames, host, host
            )
            compression = DEFAULT_COMPRESSION
        self._append(frame, compression)

    def side_by_side(self, t_ns: int, msg: Any, topic: str) -> None:
        image = _decode(msg, topic)
        if image.shape[1] % 2:
            raise BagError(
                f"{topic} is {image.shape[1]} pixels wide, not two equal eyes side by side"
            )
        half = image.shape[1] // 2
        host = self.host(t_ns)
        self._append(
            StereoFrame(image[:, :half].copy(), image[:, half:].copy(), self.frames, host, host),
            DEFAULT_COMPRESSION,
        )

    def _append(self, frame: StereoFrame, compression: str) -> None:
        if self.writer is None:
            height, width = frame.left.shape[:2]
            self.writer = SessionWriter(
                self.out, (width, height), compression, self.metadata, self.calibration_yaml
            )  # force axes x, y, z
        if frame.left.shape != frame.right.shape:
            raise BagError(
                f"frame {self.frames}: the left image is {frame.left.shape[:2]}, the "
                f"right {frame.right.shape[:2]}; vbfe needs equal eyes"
            )
        self.writer.append_frames([frame])
        self.frames += 1
        if self.frames % _FLUSH_FRAMES == 0:
            self.flush()

    def force(self, t_ns: int, force_n: np.ndarray) -> None:
        host = self.host(t_ns)
        self.pending_forces.append(ForceSample(force_n, self.forces, host, host))
        self.forces += 1

    def event(self, t_ns: int, msg: Any) -> None:
        self.pending_events.append(
            ProjectorEvent(
                pattern=msg.pattern,
                frame_id=msg.frame_id,
                seq=msg.seq,
                t_host_ns=self.host(t_ns),
                t_device_ns=-1,
            )
        )

    def flush(self) -> None:
        if self.writer is not None:
            self.writer.append_forces(self.pending_forces)
            self.writer.append_events(self.pending_events)
            self.pending_forces, self.pending_events = [], []
            self.writer.flush(self.clock_pair())


def _force_vector(msg: Any) -> np.ndarray:
    vector = (
        msg.wrench.force
        if hasattr(msg, "wrench")
        else (msg.force if hasattr(msg, "force") else msg.vector)
    )
    return np.array([vector.x, vector.y, vector.z], np.float64)


def import_bag(
    bag_path: str | Path,
    out_path: str | Path,
    given: TopicChoice,
    on_progress: Callable[[int], None] | None = None,
) -> ImportSummary:
    """Write the chosen topics of a bag as a session ``out_path`` (under a temporary name
    renamed when complete); ``on_progress(frames)`` as frames are written."""
    out_path = Path(out_path)
    try:
        with atomic_path(out_path) as tmp:
            return _import(bag_path, out_path, tmp, given, on_progress)
    except _DAMAGED as exc:
        raise BagError(
            f"{bag_path} is damaged and cannot be read to the end ({type(exc).__name__}: {exc})"
        ) from None


def _import(
    bag_path: str | Path,
    out_path: Path,
    tmp: Path,
    given: TopicChoice,
    on_progress: Callable[[int], None] | None,
) -> ImportSummary:
    with open_bag(bag_path) as reader:
        topics = topic_types(reader)
        choice = choose_topics(topics, given)
        vbfe_session = _first_string(reader, TOPICS["session"])
        session = json.loads(vbfe_session) if vbfe_session else {}
        metadata = {
            **session.get("metadata", {}),
            "imported_from": str(Path(bag_path).absolute()),
            "imported_topics": {k: v for k, v in vars(choice).items() if isinstance(v, str)},
        }
        metadata.setdefault("protocol", {"kind": "traction"})
        calibration, how = _calibration(reader, topics, choice)
        sink = _SessionSink(tmp, metadata, calibration)
        try:
            _copy_messages(reader, topics, choice, sink, on_progress)
            if sink.writer is None:
                raise BagError(
                    f"{bag_path} has no complete stereo frame on the chosen topics "
                    f"({choice.image or f'{choice.left}, {choice.right}'})"
                )
            sink.flush()
            sink.writer.close(sink.clock_pair())
            first_ns = sink.base_ns or 0
            finalize_session(
                tmp,
                {
                    "start_utc_ns": first_ns,
                    "start_host_ns": _HOST_START_NS,
                    "end_utc_ns": sink.last_ns,
                    "end_host_ns": sink.host(sink.last_ns),
                    "end_reason": f"imported from {Path(bag_path).name}",
                },
            )
        except BaseException:
            if sink.writer is not None:
                sink.writer.abort()
            raise
    return ImportSummary(
        out_path,
        sink.frames,
        sink.forces,
        sink.unpaired,
        how,
        {k: v for k, v in vars(choice).items() if isinstance(v, str)},
    )


def _first_string(reader: AnyReader, topic: str) -> str | None:
    connections = [
        c for c in reader.connections if c.topic == topic and c.msgtype == "std_msgs/msg/String"
    ]
    if not connections:  # rosbags reads every topic when given none
        return None
    for connection, _, raw in reader.messages(connections=connections):
        message: Any = reader.deserialize(raw, connection.msgtype)  # a std_msgs/String
        return message.data
    return None


def _calibration(
    reader: AnyReader, topics: dict[str, str], choice: TopicChoice
) -> tuple[str | None, str]:
    """The calibration YAML and where it came from."""
    yaml_text = _first_string(reader, TOPICS["calibration"])
    if yaml_text is not None:
        return yaml_text, "vbfe"
    if choice.left_info is None or choice.right_info is None:
        return None, "none: no camera_info for both eyes"
    infos = {}
    for eye, topic in (("left", choice.left_info), ("right", choice.right_info)):
        connections = [c for c in reader.connections if c.topic == topic]
        for connection, _, raw in reader.messages(connections=connections):
            infos[eye] = reader.deserialize(raw, connection.msgtype)
            break
    if len(infos) < 2:
        return None, "none: a camera_info topic has no message"
    try:
        return calibration_from_camera_info(infos["left"], infos["right"]), "camera_info"
    except BagError as exc:
        return None, f"none: {exc}"


def _copy_messages(
    reader: AnyReader,
    topics: dict[str, str],
    choice: TopicChoice,
    sink: _SessionSink,
    on_progress: Callable[[int], None] | None,
) -> None:
    eyes = {choice.left: "left", choice.right: "right"} if choice.image is None else {}
    wanted = {*eyes, choice.image, choice.force}
    if topics.get(TOPICS["projector"]) == "vbfe_msgs/msg/ProjectorEvent":
        wanted.add(TOPICS["projector"])
    connections = [c for c in reader.connections if c.topic in wanted]
    pairer = _Pairer(int(choice.pair_tolerance_s * 1e9))
    for connection, bag_ns, raw in reader.messages(connections=connections):
        msg = reader.deserialize(raw, connection.msgtype)
        t_ns = _time_ns(msg, bag_ns)
        if sink.base_ns is None:
            sink.base_ns = t_ns
        sink.last_ns = max(sink.last_ns, t_ns)
        topic = connection.topic
        if topic == choice.force:
            sink.force(t_ns, _force_vector(msg))
        elif topic == choice.image:
            sink.side_by_side(t_ns, msg, topic)
        elif topic in eyes:
            for t_pair, left, right in pairer.add(eyes[topic], t_ns, msg):
                sink.frame(t_pair, left, right, (choice.left, choice.right))
                if on_progress is not None:
                    on_progress(sink.frames)
        else:
            sink.event(t_ns, msg)
    sink.unpaired = pairer.unpaired + sum(map(len, pairer.queues.values()))
