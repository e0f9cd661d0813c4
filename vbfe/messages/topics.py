"""ROS 2 message definitions of the exported topics, taken from rosbags' type store (the
standard ones) or registered there from the ``vbfe_msgs`` texts below; topic names; the
host-to-Unix time map of a session."""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

# vbfe's own messages (ROS 2 .msg syntax); header.stamp is the synchronized Unix time.
CUSTOM_MSGS = {
    "vbfe_msgs/msg/ProjectorEvent": "std_msgs/Header header\nstring pattern\nint64 frame_id\n"
    "int64 seq\n",
    "vbfe_msgs/msg/Gap": "std_msgs/Header header\nstring stream\nstring reason\nint64 last_seq\n"
    "int64 next_seq\nint64 count\n",
    # lo_n, hi_n: the prediction interval per axis (empty: the model has none); ood: the frame
    # is outside the model's training data (false too when the model has no such flag)
    "vbfe_msgs/msg/ForceEstimate": "std_msgs/Header header\nstring target\nstring[] axes\n"
    "float64[] force_n\nfloat64[] lo_n\nfloat64[] hi_n\nbool ood\nint64 frame_seq\n"
    "float64 latency_s\n",
}

TOPICS = {
    "left_image": "/stereo/left/image_raw",
    "right_image": "/stereo/right/image_raw",
    "left_info": "/stereo/left/camera_info",
    "right_info": "/stereo/right/camera_info",
    "wrench": "/trocar/wrench",
    "points": "/stereo/points",
    "projector": "/projector/events",
    "gaps": "/vbfe/gaps",
    "estimate": "/vbfe/estimate",
    "session": "/vbfe/session",
    "calibration": "/vbfe/calibration",
}
FRAME_IDS = {
    "left": "stereo_left_optical",
    "right": "stereo_right_optical",
    "trocar": "trocar",
    "points": "stereo_left_rectified",
}
MIN_UNIX_NS = 946_684_800 * 10**9  # 2000-01-01: anything earlier is not a wall-clock time


@cache
def typestore() -> Typestore:
    """ROS 2 Humble's standard messages plus ``vbfe_msgs``."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, text in CUSTOM_MSGS.items():
        store.register(get_types_from_msg(text, name))
    return store


def schema_text(msgtype: str) -> str:
    """The ROS 2 ``.msg`` text of ``msgtype`` with its dependencies (MCAP ``ros2msg`` schema)."""
    return typestore().generate_msgdef(msgtype, ros_version=2)[0]


def stamp_ns(value: Any) -> int:
    """Unix nanoseconds of a ``builtin_interfaces/Time`` (ROS 1 or 2, as rosbags reads it)."""
    return int(value.sec) * 10**9 + int(getattr(value, "nanosec", getattr(value, "nsec", 0)))


def host_to_unix(
    clock_pairs: np.ndarray, start_utc_ns: int | None, start_host_ns: int | None
) -> tuple[int, int] | None:
    """``(host_ref, utc_ref)`` so ``utc = host - host_ref + utc_ref``: the median offset of the
    session's (UTC, host) clock pairs, else its start attributes; None without either."""
    pairs = np.asarray(clock_pairs, np.int64).reshape(-1, 2)
    pairs = pairs[(pairs[:, 0] > 0) & (pairs[:, 1] > 0)]
    if len(pairs):
        offsets = pairs[:, 0] - pairs[:, 1]
        return int(pairs[0, 1]), int(pairs[0, 1] + np.median(offsets))
    if start_utc_ns and start_host_ns:
        return int(start_host_ns), int(start_utc_ns)
    return None
