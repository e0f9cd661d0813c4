"""Stereo endoscope on V4L2 through linuxpy: memory-mapped streaming with the kernel's buffers.

Each dequeued buffer carries the kernel's timestamp and sequence number: device time is that
timestamp (``V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC``: CLOCK_MONOTONIC, the clock of
``time.monotonic_ns``; the flags say which clock and whether it marks start of exposure or end
of frame, and ``describe()`` reports it), and the sequence number counts every frame the driver
produced, so frames the kernel dropped show as exact sequence gaps. MJPEG frames are kept as the
camera's own bytes (:class:`~vbfe.drivers.samples.JpegStereoFrame`), decoded only when someone
looks at ``left``/``right``; the recorder's ``mjpeg`` storage writes them as they are. YUYV is
converted to BGR. Controls (exposure, gain, white balance, auto modes) are set by the names the
device reports (``v4l2-ctl --list-ctrls``, ``vbfe devices``), auto modes first, read back and
reported in ``describe()``.

Two devices ``[left, right]`` are paired by kernel timestamp (a lone frame is discarded, which
shows as a gap of the left sequence); one side-by-side device is split in two, which needs a
decode, so its MJPEG bytes are not kept.
"""

from __future__ import annotations

import errno
import select
import time
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.samples import JpegStereoFrame, StereoFrame

FOURCCS = ("MJPG", "YUYV")
BUF_FLAG_TIMESTAMP_MASK = 0xE000  # linux/videodev2.h
BUF_FLAG_TIMESTAMP_MONOTONIC = 0x2000
BUF_FLAG_TIMESTAMP_COPY = 0x4000
BUF_FLAG_TSTAMP_SRC_SOE = 0x10000
BUF_FLAG_ERROR = 0x40
MEMORY_MMAP = 1  # enum v4l2_memory
ControlValue = int | bool


def linuxpy_device(path: str) -> Any:
    """A linuxpy ``Device`` for ``path``, non-blocking (reads wait in ``select``)."""
    from linuxpy.video.device import Device

    return Device(path, blocking=False)


def linuxpy_capture(device: Any, buffers: int) -> Any:
    """linuxpy's memory-mapped ``VideoCapture`` on ``device`` with ``buffers`` kernel buffers."""
    from linuxpy.video.device import VideoCapture

    return VideoCapture(device, size=buffers)


def fourcc_name(code: int) -> str:
    """The four characters of a V4L2 pixel format code (``MJPG``, ``YUYV``)."""
    return "".join(chr((int(code) >> 8 * i) & 0xFF) for i in range(4))


def timestamp_clock(flags: int) -> str:
    """Which clock a V4L2 buffer's timestamp is on and what instant it marks, from its flags."""
    kind = flags & BUF_FLAG_TIMESTAMP_MASK
    clock = {
        BUF_FLAG_TIMESTAMP_MONOTONIC: "CLOCK_MONOTONIC",
        BUF_FLAG_TIMESTAMP_COPY: "copied from the output stream",
    }.get(kind, "unknown clock")
    source = "start of exposure" if flags & BUF_FLAG_TSTAMP_SRC_SOE else "end of frame"
    return f"V4L2 buffer timestamp ({clock}, {source})"


def buffer_time_ns(buff: Any) -> int:
    """A v4l2_buffer's timestamp (struct timeval) in integer nanoseconds."""
    return int(buff.timestamp.secs) * 1_000_000_000 + int(buff.timestamp.usecs) * 1_000


class _Node:
    """One open V4L2 node: the linuxpy device, its capture stream and the frame held back."""

    def __init__(self, path: str, device: Any, capture: Any) -> None:
        self.path, self.device, self.capture = path, device, capture
        self.pending: Any = None  # a frame read but not yet paired

    def wait(self, timeout_s: float) -> bool:
        """Whether a buffer is ready within ``timeout_s``."""
        ready, _, _ = select.select([self.device], [], [], max(timeout_s, 0.0))
        return bool(ready)

    def take(self, timeout_s: float) -> Any | None:
        """The held-back frame or the next dequeued one; None when none came in time."""
        if self.pending is not None:
            frame, self.pending = self.pending, None
            return frame
        if not self.wait(timeout_s):
            return None
        try:
            return self.capture.buffer.raw_read()
        except BlockingIOError:
            return None


class LinuxpyStereoCamera(StereoCamera):
    """A stereo endoscope on V4L2: ``devices=[left, right]`` or one side-by-side ``device``.

    ``width``/``height`` are per eye; a side-by-side device is asked for ``2*width × height``.
    ``fourcc`` is the pixel format the camera sends (``"MJPG"`` or ``"YUYV"``). ``controls``
    maps V4L2 control names to values, e.g. ``{auto_exposure = 1, exposure_time_absolute = 100,
    gain = 0, white_balance_automatic = false, white_balance_temperature = 4600}``.
    """

    def __init__(
        self,
        device: str | None = None,
        devices: Sequence[str] | None = None,
        width: int = 1920,
        height: int = 1080,
        fps: float = 30.0,
        fourcc: str = "MJPG",
        controls: dict[str, ControlValue] | None = None,
        buffers: int = 4,
        stall_timeout_s: float = 5.0,
        device_factory: Callable[[str], Any] = linuxpy_device,
        capture_factory: Callable[[Any, int], Any] = linuxpy_capture,
        host_clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        super().__init__()
        if (device is None) == (devices is None):
            raise DeviceError(
                "give the camera either device (one side-by-side device) or devices = [left, right]"
            )
        self.paths = [str(device)] if device is not None else [str(d) for d in devices or []]
        if len(self.paths) not in (1, 2):
            raise DeviceError(f"camera devices must be [left, right], got {self.paths}")
        if fourcc not in FOURCCS:
            raise DeviceError(f"camera fourcc {fourcc!r} is not supported; use one of {FOURCCS}")
        self.width, self.height, self.fps, self.fourcc = int(width), int(height), float(fps), fourcc
        self.requested_controls = dict(controls or {})
        self.buffers, self.stall_timeout_s = int(buffers), float(stall_timeout_s)
        self._device_factory, self._capture_factory = device_factory, capture_factory
        self._host_clock = host_clock
        self._nodes: list[_Node] = []
        self.controls: dict[str, dict[str, ControlValue]] = {}  # per node: read back
        self.clock = "V4L2 buffer timestamp"  # which clock: from the buffer flags at open
        self._last_good = 0.0

    @property
    def label(self) -> str:
        """The camera and its device node(s)."""
        return f"camera {', '.join(self.paths)}"

    @property
    def side_by_side(self) -> bool:
        """One device carrying both eyes next to each other."""
        return len(self.paths) == 1

    def _open(self) -> None:
        """Open the node(s), set format, size, rate and controls, and start streaming."""
        try:
            for path in self.paths:
                self._open_node(path)
            for node in self._nodes:
                node.capture.open()
            self.clock = timestamp_clock(
                int(self._nodes[0].capture.query_buffer(MEMORY_MMAP, 0).flags)
            )
        except DeviceError:
            self._close()
            raise
        except OSError as exc:
            self._close()
            raise DeviceError(
                f"cannot start {self.label}: {exc}; check it is plugged in, that "
                "you may read it (group 'video') and 'v4l2-ctl --list-devices'"
            ) from None
        self._last_good = time.monotonic()

    def _open_node(self, path: str) -> None:
        try:
            device = self._device_factory(path)
            device.open()
        except OSError as exc:
            raise DeviceError(
                f"cannot open camera {path}: {exc.strerror or exc}; check it is "
                "plugged in, that you may read it (group 'video') and "
                "'v4l2-ctl --list-devices'"
            ) from None
        node = _Node(path, device, None)
        self._nodes.append(node)  # closed by _close if what follows fails
        node.capture = self._capture_factory(device, self.buffers)
        want_w = 2 * self.width if self.side_by_side else self.width
        node.capture.set_format(want_w, self.height, self.fourcc)
        got = node.capture.get_format()
        if (got.width, got.height, fourcc_name(got.pixel_format)) != (
            want_w,
            self.height,
            self.fourcc,
        ):
            raise DeviceError(
                f"camera {path} gives {got.width}x{got.height} "
                f"{fourcc_name(got.pixel_format)}, not the requested "
                f"{want_w}x{self.height} {self.fourcc}; list its modes with "
                f"'vbfe devices' or 'v4l2-ctl -d {path} --list-formats-ext'"
            )
        node.capture.set_fps(self.fps)
        actual = float(node.capture.get_fps())
        if actual > 0:
            self.fps = actual
        self.controls[path] = self._apply_controls(path, device)

    def _apply_controls(self, path: str, device: Any) -> dict[str, ControlValue]:
        """Set the requested controls (auto modes first) and read every one back."""
        by_name = {c.config_name: c for c in device.controls.values()}
        unknown = [name for name in self.requested_controls if name not in by_name]
        if unknown:
            raise DeviceError(
                f"camera {path} has no control {unknown[0]!r}; it has "
                f"{', '.join(sorted(by_name))} (see 'vbfe devices')"
            )
        order = sorted(self.requested_controls, key=lambda name: "auto" not in name)
        readback: dict[str, ControlValue] = {}
        for name in order:
            want = self.requested_controls[name]
            control = by_name[name]
            try:
                control.value = want
                got = control.value
            except (AttributeError, OSError, ValueError) as exc:
                raise DeviceError(
                    f"camera {path} refused control {name} = {want!r}: {exc}"
                ) from None
            if got != want:
                raise DeviceError(
                    f"camera {path} control {name}: set {want!r}, reads back "
                    f"{got!r} (range {control.minimum}..{control.maximum}, step "
                    f"{control.step}); choose a value it accepts"
                )
            readback[name] = got
        return readback

    def _close(self) -> None:
        """Stop streaming and release the node(s)."""
        for node in self._nodes:
            releases = (
                [node.device.close]
                if node.capture is None
                else [node.capture.close, node.device.close]
            )
            for release in releases:
                try:
                    release()
                except (OSError, ValueError):  # a vanished device cannot be released cleanly
                    pass
        self._nodes = []

    def _take(self, node: _Node, timeout_s: float) -> Any | None:
        try:
            frame = node.take(timeout_s)
        except OSError as exc:
            if exc.errno in (errno.ENODEV, errno.EIO, errno.ENXIO, errno.EBADF):
                raise DeviceError(
                    f"camera {node.path} vanished (unplugged or powered off); "
                    "reconnect it and start again"
                ) from None
            raise DeviceError(f"camera {node.path} failed: {exc}") from None
        if frame is not None:
            self._last_good = time.monotonic()
            if int(frame.buff.flags) & BUF_FLAG_ERROR:  # the driver says the data is corrupt
                self.stats.malformed += 1
                return None
        elif time.monotonic() - self._last_good > self.stall_timeout_s:
            raise DeviceError(
                f"camera {node.path} delivered no frame for "
                f"{self.stall_timeout_s} s; check cable, power and "
                "'v4l2-ctl --list-devices'"
            )
        return frame

    def _read_sample(self, timeout_s: float) -> StereoFrame | None:
        """The next frame pair: dequeued buffer(s), paired by kernel timestamp when two."""
        deadline = time.monotonic() + timeout_s
        left = self._take(self._nodes[0], timeout_s)
        if left is None:
            return None
        if self.side_by_side:
            return self._frame([left], self._host_clock())
        while True:
            right = self._take(self._nodes[1], deadline - time.monotonic())
            if right is None:
                self._nodes[0].pending = left  # pair it on the next call
                return None
            lag = buffer_time_ns(left.buff) - buffer_time_ns(right.buff)
            if abs(lag) <= 5e8 / self.fps:
                return self._frame([left, right], self._host_clock())
            if lag > 0:  # the right frame is older: its partner is gone, take the next
                continue
            self._nodes[1].pending = right  # the left frame is older: take the next left
            left = self._take(self._nodes[0], deadline - time.monotonic())
            if left is None:
                return None

    def _frame(self, frames: list[Any], t_host_ns: int) -> StereoFrame:
        head = frames[0]
        seq, t_device_ns = int(head.buff.sequence), buffer_time_ns(head.buff)
        if self.fourcc == "MJPG" and not self.side_by_side:
            return JpegStereoFrame(
                (bytes(frames[0].data), bytes(frames[1].data)), seq, t_device_ns, t_host_ns
            )
        images = [self._decode(frame) for frame in frames]
        if self.side_by_side:
            half = images[0].shape[1] // 2
            images = [images[0][:, :half], images[0][:, half : 2 * half]]
        return StereoFrame(
            left=np.ascontiguousarray(images[0]),
            right=np.ascontiguousarray(images[1]),
            seq=seq,
            t_device_ns=t_device_ns,
            t_host_ns=t_host_ns,
        )

    def _decode(self, frame: Any) -> np.ndarray:
        data = np.frombuffer(frame.data, np.uint8)
        if self.fourcc == "YUYV":
            width = 2 * self.width if self.side_by_side else self.width
            return cv2.cvtColor(
                data[: width * self.height * 2].reshape(self.height, width, 2),
                cv2.COLOR_YUV2BGR_YUYV,
            )
        image = cv2.imdecode(data, cv2.IMREAD_COLOR)
        if image is None:
            raise DeviceError(f"{self.label}: frame {frame.buff.sequence} is not a JPEG")
        return image

    def describe(self) -> dict[str, object]:
        """Static facts for session metadata: nodes, layout, format, rate, clock, controls."""
        return {
            **super().describe(),
            "backend": "linuxpy",
            "devices": list(self.paths),
            "layout": "side-by-side" if self.side_by_side else "two-devices",
            "fourcc": self.fourcc,
            "buffers": self.buffers,
            "device_clock": self.clock,
            "controls": {path: dict(values) for path, values in self.controls.items()},
        }
