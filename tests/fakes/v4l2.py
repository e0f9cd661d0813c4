"""A fake V4L2 camera node at linuxpy's device boundary.

:class:`FakeV4L2Node` stands in for ``linuxpy.video.device.Device`` (open/close, ``fileno`` for
``select``, ``controls``, ``info``) and :class:`FakeCapture` for ``VideoCapture`` (format, rate,
stream on/off, ``buffer.raw_read()``, ``query_buffer``). Frames are linuxpy's own ``Frame``
objects around real ``v4l2_buffer`` structs carrying the kernel's sequence number, timestamp and
flags; the data is a JPEG (or YUYV) of :func:`tests.fakes.camera.render_eye` (a JPEG is
followed by its sequence number, after the end marker, so every frame's bytes differ). The node can
drop sequence numbers, flag buffers as corrupt, vanish (``ENODEV``) after some frames, and, paced in
real time, lose frames the way the kernel does when all buffers are full; nodes given the same
``start_ns`` are a hardware-synchronized stereo head (else each starts its frames at its own
stream-on).
``delivered`` keeps every byte string handed out.
"""

from __future__ import annotations

import collections
import errno
import os
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
from linuxpy.video import raw
from linuxpy.video.device import (
    BufferType,
    Format,
    Frame,
    FrameIntervalType,
    FrameType,
    ImageFormat,
)

from tests.fakes.camera import DISPARITY_PX, render_eye

MONOTONIC_SOE = 0x2000 | 0x10000  # V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | TSTAMP_SRC_SOE
BUF_FLAG_ERROR = 0x40
FOURCC_CODES = {"MJPG": raw.v4l2_fourcc(*"MJPG"), "YUYV": raw.v4l2_fourcc(*"YUYV")}


@dataclass
class FakeControl:
    """A V4L2 integer/boolean/menu control as linuxpy presents it (``config_name``, ``value``)."""

    config_name: str
    minimum: int
    maximum: int
    step: int = 1
    default: int = 0
    inactive_unless: tuple[str, int] | None = None  # (control, value) that makes it writable
    node: FakeV4L2Node | None = None
    current: int | None = None

    @property
    def value(self) -> int:
        return self.default if self.current is None else self.current

    @value.setter
    def value(self, value: int) -> None:
        if self.inactive_unless is not None and self.node is not None:
            name, needed = self.inactive_unless
            if self.node.controls_by_name[name].value != needed:
                raise AttributeError(
                    f"IntegerControl {self.config_name} is not writeable: inactive"
                )
        clipped = min(max(int(value), self.minimum), self.maximum)
        self.current = self.minimum + (clipped - self.minimum) // self.step * self.step


def default_controls() -> list[FakeControl]:
    """The exposure/gain/white-balance controls of a typical UVC endoscope."""
    return [
        FakeControl("auto_exposure", 0, 3, 1, 3),  # 1 = manual, 3 = aperture priority
        FakeControl("exposure_time_absolute", 3, 2047, 1, 156, ("auto_exposure", 1)),
        FakeControl("gain", 0, 255, 1, 32),
        FakeControl("white_balance_automatic", 0, 1, 1, 1),
        FakeControl(
            "white_balance_temperature", 2800, 6500, 10, 4600, ("white_balance_automatic", 0)
        ),
    ]


def yuyv_bytes(image: np.ndarray) -> bytes:
    """A BGR image packed as YUYV 4:2:2 (Y0 U Y1 V), video range as cameras send it (through
    OpenCV's BT.601 I420 conversion, chroma rows repeated)."""
    h, w = image.shape[:2]
    planes = cv2.cvtColor(image, cv2.COLOR_BGR2YUV_I420).reshape(-1)
    y = planes[: h * w].reshape(h, w)
    u = planes[h * w : h * w * 5 // 4].reshape(h // 2, w // 2).repeat(2, axis=0)
    v = planes[h * w * 5 // 4 :].reshape(h // 2, w // 2).repeat(2, axis=0)
    out = np.empty((h, w, 2), np.uint8)
    out[..., 0], out[:, 0::2, 1], out[:, 1::2, 1] = y, u, v
    return out.tobytes()


class FakeV4L2Node:
    """One ``/dev/videoN`` of a stereo endoscope: ``eye`` is ``left``, ``right`` or ``both``."""

    def __init__(
        self,
        path: str,
        width: int = 64,
        height: int = 48,
        fps: float = 30.0,
        fourcc: str = "MJPG",
        eye: str = "left",
        n_frames: int | None = None,
        drop_seqs: Iterable[int] = (),
        vanish_after: int | None = None,
        error_seqs: Iterable[int] = (),
        realtime: bool = False,
        timestamp_flags: int = MONOTONIC_SOE,
        clock_offset_ns: int = 0,
        controls: list[FakeControl] | None = None,
        start_ns: int | None = None,
    ) -> None:
        self.path, self.width, self.height, self.fps = path, width, height, float(fps)
        self.fourcc, self.eye, self.n_frames = fourcc, eye, n_frames
        self.drop_seqs, self.vanish_after = frozenset(drop_seqs), vanish_after
        self.error_seqs = frozenset(error_seqs)  # delivered with V4L2_BUF_FLAG_ERROR
        self.realtime, self.timestamp_flags, self.clock_offset_ns = (
            realtime,
            timestamp_flags,
            clock_offset_ns,
        )
        self.controls_by_name = {c.config_name: c for c in (controls or default_controls())}
        for control in self.controls_by_name.values():
            control.node = self
        self.controls = SimpleNamespace(values=lambda: list(self.controls_by_name.values()))
        self.info = SimpleNamespace(
            card=f"Fake endoscope {eye}",
            formats=[
                ImageFormat(BufferType.VIDEO_CAPTURE, name, 0, FOURCC_CODES[name])
                for name in ("MJPG", "YUYV")
            ],
            frame_types=[
                FrameType(
                    FrameIntervalType.DISCRETE,
                    FOURCC_CODES[name],
                    self.frame_width,
                    height,
                    rate,
                    rate,
                    rate,
                )
                for name in ("MJPG", "YUYV")
                for rate in (30, 15)
            ],
        )
        self.delivered: dict[int, bytes] = {}
        self.times: dict[int, int] = {}  # kernel timestamp (ns, µs resolution) per delivered seq
        self.kernel_dropped: list[int] = []
        self.closed = True
        self.format: tuple[int, int, int] | None = None
        self._fds: tuple[int, int] | None = None
        self._next_seq, self._lock = 0, threading.Lock()
        self._filled: collections.deque[int] = collections.deque()  # sequence numbers in buffers
        self._streaming = threading.Event()
        self._pacer: threading.Thread | None = None
        self._t0_ns, self.start_ns = 0, start_ns  # start_ns: frame 0's time (a shared trigger)

    @property
    def frame_width(self) -> int:
        return 2 * self.width if self.eye == "both" else self.width

    # -- linuxpy Device surface ------------------------------------------------------------
    def open(self) -> None:
        self._fds = os.pipe()
        self.closed = False

    def close(self) -> None:
        self.stream_off()
        if self._fds is not None:
            for fd in self._fds:
                os.close(fd)
            self._fds = None
        self.closed = True

    def fileno(self) -> int:
        return self._fds[0]

    # -- streaming ---------------------------------------------------------------------------
    def stream_on(self) -> None:
        self._t0_ns = time.monotonic_ns() if self.start_ns is None else self.start_ns
        self._streaming.set()
        if self.realtime:
            self._pacer = threading.Thread(target=self._pace, daemon=True, name="fake-v4l2")
            self._pacer.start()
        else:
            self._fill_next()

    def stream_off(self) -> None:
        self._streaming.clear()
        if self._pacer is not None:
            self._pacer.join(timeout=2.0)
            self._pacer = None

    def _signal(self, seq: int) -> None:
        with self._lock:
            self._filled.append(seq)
        os.write(self._fds[1], b"x")

    def _fill_next(self) -> None:
        """Not paced: the next sequence number not dropped is ready at once."""
        seq = self._next_seq
        while seq in self.drop_seqs:
            seq += 1
        self._next_seq = seq + 1
        if self.n_frames is None or seq < self.n_frames:
            self._signal(seq)

    def _pace(self) -> None:
        """Make a frame ready at each period; lose it when all buffers are full (the kernel)."""
        k = 0
        while self._streaming.is_set() and (self.n_frames is None or k < self.n_frames):
            delay = (self._t0_ns + k / self.fps * 1e9 - time.monotonic_ns()) / 1e9
            if delay > 0:
                time.sleep(delay)
            with self._lock:
                full = len(self._filled) >= self.buffers
            if full:
                self.kernel_dropped.append(k)
            elif self._streaming.is_set():
                self._signal(k)
            k += 1

    buffers = 4

    def _time_ns(self, seq: int) -> int:
        return self._t0_ns + self.clock_offset_ns + round(seq * 1e9 / self.fps)

    def _image(self, seq: int) -> bytes:
        left = render_eye(self.width, self.height, seq)
        right = render_eye(self.width, self.height, seq, shift_px=DISPARITY_PX)
        image = {"both": np.hstack([left, right]), "left": left, "right": right}[self.eye]
        if self.fourcc == "YUYV":
            return yuyv_bytes(image)
        jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
        return jpeg + seq.to_bytes(4, "little")  # after the end marker: unique, ignored by decoders

    def raw_read(self) -> Frame:
        """Dequeue the next buffer (``VIDIOC_DQBUF``)."""
        if self.vanish_after is not None and len(self.delivered) >= self.vanish_after:
            raise OSError(errno.ENODEV, "No such device")
        with self._lock:
            if not self._filled:
                raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")
            seq = self._filled.popleft()
        os.read(self._fds[0], 1)
        data = self._image(seq)
        self.delivered[seq] = data
        if not self.realtime:
            self._fill_next()
        buff = raw.v4l2_buffer()
        flags = self.timestamp_flags | (BUF_FLAG_ERROR if seq in self.error_seqs else 0)
        buff.sequence, buff.flags, buff.bytesused = seq, flags, len(data)
        t_ns = self._time_ns(seq) // 1000 * 1000
        self.times[seq] = t_ns
        buff.timestamp.secs, buff.timestamp.usecs = t_ns // 10**9, t_ns % 10**9 // 1000
        return Frame(data, buff, self._format())

    def _format(self) -> Any:
        return Format(self.frame_width, self.height, FOURCC_CODES[self.fourcc], 0, 0)


class FakeCapture:
    """linuxpy's ``VideoCapture`` on a :class:`FakeV4L2Node`."""

    def __init__(self, node: FakeV4L2Node, size: int) -> None:
        self.node, self.size = node, size
        node.buffers = size
        self.buffer = SimpleNamespace(raw_read=node.raw_read)
        self.fps = node.fps

    def set_format(self, width: int, height: int, pixel_format: str = "MJPG") -> None:
        if pixel_format in FOURCC_CODES:  # one fixed size: other sizes are not taken
            self.node.fourcc = pixel_format

    def get_format(self) -> Any:
        return self.node._format()

    def set_fps(self, fps: float) -> None:
        self.fps = fps if fps in (15, 30) else self.node.fps

    def get_fps(self) -> float:
        return self.fps

    def query_buffer(self, memory: int, index: int) -> Any:
        buff = raw.v4l2_buffer()
        buff.index, buff.memory, buff.flags = index, memory, self.node.timestamp_flags
        return buff

    def open(self) -> None:
        self.node.stream_on()

    def close(self) -> None:
        self.node.stream_off()


def fake_factories(*nodes: FakeV4L2Node) -> dict[str, Any]:
    """``device_factory``/``capture_factory`` keyword arguments serving ``nodes`` by path."""
    by_path = {node.path: node for node in nodes}

    def device(path: str) -> FakeV4L2Node:
        if path not in by_path:
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", path)
        return by_path[path]

    return {"device_factory": device, "capture_factory": FakeCapture}
