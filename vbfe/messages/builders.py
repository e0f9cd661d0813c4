"""The ROS 2 messages vbfe writes, built from its records: for the MCAP export and the live
Foxglove server alike (each one's topic, type and frame id are written once, here and in
:mod:`vbfe.messages.topics`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from vbfe.messages.topics import FRAME_IDS, typestore

_FLOAT32 = 7  # sensor_msgs/PointField.FLOAT32
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
WRENCH = "geometry_msgs/msg/WrenchStamped"
POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
PROJECTOR_EVENT = "vbfe_msgs/msg/ProjectorEvent"


def msg(msgtype: str, **fields: Any) -> Any:
    """A message object of rosbags' type store (ROS 2 Humble + vbfe_msgs)."""
    return typestore().types[msgtype](**fields)


def cdr(message: Any, msgtype: str) -> bytes:
    """``message`` serialized as CDR (what an MCAP ``cdr`` channel or Foxglove receives)."""
    return bytes(typestore().serialize_cdr(message, msgtype))


def header(t_ns: int, frame_id: str) -> Any:
    """A ``std_msgs/Header`` stamped ``t_ns`` (Unix ns)."""
    t_ns = int(t_ns)
    return msg(
        "std_msgs/msg/Header",
        frame_id=frame_id,
        stamp=msg("builtin_interfaces/msg/Time", sec=t_ns // 10**9, nanosec=t_ns % 10**9),
    )


def compressed_image(t_ns: int, eye: str, image_format: str, data: bytes) -> Any:
    """One eye's image as ``sensor_msgs/CompressedImage`` (``png`` or ``jpeg`` bytes)."""
    return msg(
        COMPRESSED_IMAGE,
        header=header(t_ns, FRAME_IDS[eye]),
        format=image_format,
        data=np.frombuffer(data, np.uint8),
    )


def raw_image(t_ns: int, eye: str, image: np.ndarray) -> Any:
    """One eye's BGR image as ``sensor_msgs/Image`` ``bgr8``."""
    height, width = image.shape[:2]
    return msg(
        IMAGE,
        header=header(t_ns, FRAME_IDS[eye]),
        height=height,
        width=width,
        encoding="bgr8",
        is_bigendian=0,
        step=width * 3,
        data=np.ascontiguousarray(image).reshape(-1),
    )


def wrench(t_ns: int, force: dict[str, float]) -> Any:
    """The trocar's force (``{"x": .., "y": .., "z": ..}``, missing axes 0) as
    ``geometry_msgs/WrenchStamped``, torque zero."""
    vector = "geometry_msgs/msg/Vector3"
    return msg(
        WRENCH,
        header=header(t_ns, FRAME_IDS["trocar"]),
        wrench=msg(
            "geometry_msgs/msg/Wrench",
            force=msg(vector, **{axis: float(force.get(axis, 0.0)) for axis in "xyz"}),
            torque=msg(vector, x=0.0, y=0.0, z=0.0),
        ),
    )


def wrench_cdr(t_ns: np.ndarray, forces: np.ndarray) -> list[bytes]:
    """Many trocar samples (Unix ns, n × 3 force x, y, z) at once as the CDR bytes of
    :func:`wrench` (torque zero): the same bytes as :func:`cdr`, packed by numpy in one go
    (rosbags builds and serializes a message in a few hundred µs: too slow for 1 kHz live)."""
    frame_id = FRAME_IDS["trocar"].encode() + b"\0"
    pad = -(8 + 4 + len(frame_id)) % 8  # float64s align to 8 after the encapsulation header
    layout = np.dtype(
        [
            ("encapsulation", "u1", 4),
            ("sec", "<i4"),
            ("nanosec", "<u4"),
            ("frame_id_len", "<u4"),
            ("frame_id", f"S{len(frame_id)}"),
            ("pad", "u1", pad),
            ("force", "<f8", 3),
            ("torque", "<f8", 3),
        ]
    )
    t_ns = np.asarray(t_ns, np.int64)
    packed = np.zeros(len(t_ns), layout)
    packed["encapsulation"] = (0, 1, 0, 0)  # CDR, little-endian
    packed["sec"], packed["nanosec"] = t_ns // 10**9, t_ns % 10**9
    packed["frame_id_len"], packed["frame_id"] = len(frame_id), frame_id
    packed["force"] = forces
    data = packed.tobytes()
    return [data[k : k + layout.itemsize] for k in range(0, len(data), layout.itemsize)]


def projector_event(t_ns: int, pattern: str, frame_id: int, seq: int) -> Any:
    """A pattern the projector showed as ``vbfe_msgs/ProjectorEvent``."""
    return msg(
        PROJECTOR_EVENT,
        header=header(t_ns, "projector"),
        pattern=pattern,
        frame_id=int(frame_id),
        seq=int(seq),
    )


def point_cloud(t_ns: int, points: np.ndarray, colors: np.ndarray) -> Any:
    """Points (n × 3, metres) and their RGB colours (n × 3) as ``sensor_msgs/PointCloud2``:
    x, y, z float32 and PCL's packed ``rgb``."""
    fields = [
        msg("sensor_msgs/msg/PointField", name=name, offset=4 * k, datatype=_FLOAT32, count=1)
        for k, name in enumerate(("x", "y", "z", "rgb"))
    ]
    rgb = np.asarray(colors).astype(np.uint32)
    packed = ((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).view(np.float32)
    data = np.column_stack([np.asarray(points, np.float32), packed])
    return msg(
        POINT_CLOUD,
        header=header(t_ns, FRAME_IDS["points"]),
        height=1,
        width=len(points),
        fields=fields,
        is_bigendian=False,
        point_step=16,
        row_step=16 * len(points),
        data=np.ascontiguousarray(data).view(np.uint8).reshape(-1),
        is_dense=True,
    )
