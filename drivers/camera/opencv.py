"""The OpenCV fallback camera backend (``backend = "opencv"``): two devices, or one
side-by-side device split in two, read through ``cv2.VideoCapture``.

Use it where linuxpy's V4L2 backend (:mod:`vbfe.drivers.camera.linuxpy_v4l2`) cannot run; it
has no buffer sequence numbers and never the camera's own JPEG bytes. A background thread grabs
frames so ``read(timeout_s)`` can time out; it blocks when the reader falls behind, so frames are
only ever lost in the kernel, where the device timestamps show it. Device time is the V4L2 buffer
timestamp (``CAP_PROP_POS_MSEC`` of OpenCV's V4L2 backend, the kernel's CLOCK_MONOTONIC at capture);
sequence numbers come from the timestamps: an interval of more than 1.5 frame periods means frames
were dropped, which the base class counts.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.samples import StereoFrame

Device = str | int
CaptureFactory = Callable[[Device], Any]  # returns an object with the cv2.VideoCapture surface


def v4l2_capture(device: Device) -> cv2.VideoCapture:
    """Open ``device`` (``/dev/videoN`` or index N) with OpenCV's V4L2 backend."""
    return cv2.VideoCapture(device, cv2.CAP_V4L2)


def device_node_present(device: Device) -> bool:
    """Whether the device node still exists; names outside /dev (test fakes) count as present."""
    if isinstance(device, int):
        return os.path.exists(f"/dev/video{device}")
    return not device.startswith("/dev/") or os.path.exists(device)


class OpenCVStereoCamera(StereoCamera):
    """A stereo endoscope on V4L2: ``devices=[left, right]`` or one side-by-side ``device``.

    ``width``/``height`` are per eye; a side-by-side device is asked for ``2*width × height``.
    ``fourcc`` is the pixel format the camera sends (``"MJPG"`` or ``"YUYV"``).
    """

    def __init__(
        self,
        device: Device | None = None,
        devices: Sequence[Device] | None = None,
        width: int = 1920,
        height: int = 1080,
        fps: float = 30.0,
        fourcc: str = "MJPG",
        capture_factory: CaptureFactory = v4l2_capture,
        host_clock: Callable[[], int] = time.monotonic_ns,
        queue_size: int = 8,
        stall_timeout_s: float = 5.0,
    ) -> None:
        super().__init__()
        if (device is None) == (devices is None):
            raise DeviceError(
                "give the camera either device (one side-by-side device) or devices = [left, right]"
            )
        self.devices: list[Device] = [device] if device is not None else list(devices or [])
        if len(self.devices) not in (1, 2):
            raise DeviceError(f"camera devices must be [left, right], got {self.devices}")
        self.width, self.height, self.fps = int(width), int(height), float(fps)
        if len(fourcc) != 4:
            raise DeviceError(f"camera fourcc must have 4 characters (MJPG, YUYV), got {fourcc!r}")
        self.fourcc = fourcc
        self._factory, self._host_clock = capture_factory, host_clock
        self.stall_timeout_s = stall_timeout_s
        self._caps: list[Any] = []
        self._queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._seq: int | None = None
        self._last_t_ns = 0

    @property
    def side_by_side(self) -> bool:
        """One device carrying both eyes next to each other."""
        return len(self.devices) == 1

    @property
    def period_ns(self) -> float:
        """Nominal frame interval in nanoseconds."""
        return 1e9 / self.fps

    @property
    def label(self) -> str:
        """The camera and its device node(s)."""
        return f"camera {self.devices}"

    def _open(self) -> None:
        """Open the device(s), set format, size and rate, and start grabbing."""
        want_w = 2 * self.width if self.side_by_side else self.width
        for dev in self.devices:
            cap = self._factory(dev)
            self._caps.append(cap)
            if not cap.isOpened():
                self._release()
                raise DeviceError(
                    f"cannot open camera {dev}; check it is plugged in, that you "
                    "may read it (group 'video') and 'v4l2-ctl --list-devices'"
                )
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*self.fourcc))
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, want_w)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
            cap.set(cv2.CAP_PROP_FPS, self.fps)
            got = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
            if got != (want_w, self.height):
                self._release()
                raise DeviceError(
                    f"camera {dev} gives {got[0]}x{got[1]}, not the requested "
                    f"{want_w}x{self.height} {self.fourcc}; list its modes with "
                    f"'v4l2-ctl -d {dev} --list-formats-ext'"
                )
            actual_fps = float(cap.get(cv2.CAP_PROP_FPS))
            if actual_fps > 0:
                self.fps = actual_fps
        self._stop.clear()
        self._seq = None
        self._thread = threading.Thread(
            target=self._grab_loop, daemon=True, name=f"v4l2-{self.devices[0]}"
        )
        self._thread.start()

    def _close(self) -> None:
        """Stop grabbing and release the device(s)."""
        self._stop.set()
        if self._thread is not None:
            while self._thread.is_alive():
                try:  # unblock a producer waiting on a full queue
                    self._queue.get_nowait()
                except queue.Empty:
                    self._thread.join(timeout=0.05)
            self._thread = None
        self._release()

    def _read_sample(self, timeout_s: float) -> StereoFrame | None:
        """The next grabbed pair, ``None`` on timeout; DeviceError when the camera vanished."""
        try:
            item = self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None
        if isinstance(item, DeviceError):
            raise item
        return item

    def describe(self) -> dict[str, object]:
        """Static facts for session metadata: devices, layout, pixel format, actual rate."""
        return {
            **super().describe(),
            "devices": [str(d) for d in self.devices],
            "layout": "side-by-side" if self.side_by_side else "two-devices",
            "fourcc": self.fourcc,
            "device_clock": "V4L2 buffer timestamp (CLOCK_MONOTONIC)",
        }

    def _release(self) -> None:
        for cap in self._caps:
            cap.release()
        self._caps = []

    def _put(self, item: StereoFrame | DeviceError) -> None:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return
            except queue.Full:
                continue

    def _grab_loop(self) -> None:
        last_good = time.monotonic()
        while not self._stop.is_set():
            try:
                grabbed = self._grab_pair()
            except DeviceError as exc:
                self._put(exc)
                return
            if grabbed is not None:
                last_good = time.monotonic()
                self._put(self._frame(*grabbed))
            elif time.monotonic() - last_good > self.stall_timeout_s:
                self._put(
                    DeviceError(
                        f"camera {self.devices} delivered no frame for "
                        f"{self.stall_timeout_s} s; check cable, power and "
                        "'v4l2-ctl --list-devices'"
                    )
                )
                return
            else:
                self._stop.wait(0.01)  # a failing grab may return at once: do not spin

    def _grab_one(self, index: int) -> int | None:
        """Grab on one device; its buffer timestamp in ns, ``None`` on a transient failure."""
        cap, dev = self._caps[index], self.devices[index]
        if not cap.grab():
            if not cap.isOpened() or not device_node_present(dev):
                raise DeviceError(
                    f"camera {dev} vanished (unplugged or powered off); "
                    "reconnect it and start again"
                )
            return None
        t_ms = float(cap.get(cv2.CAP_PROP_POS_MSEC))
        return round(t_ms * 1e6) if t_ms > 0 else self._host_clock()

    def _grab_pair(self) -> tuple[list[np.ndarray], int, int] | None:
        stamps = []
        for i in range(len(self._caps)):
            stamp = self._grab_one(i)
            if stamp is None:
                return None
            stamps.append(stamp)
        t_host_ns = self._host_clock()
        if not self.side_by_side:  # re-grab the eye that lags until both show the same instant
            for _ in range(4):
                lag = stamps[0] - stamps[1]
                if abs(lag) <= self.period_ns / 2:
                    break
                behind = 1 if lag > 0 else 0
                stamp = self._grab_one(behind)
                if stamp is None:
                    return None
                stamps[behind] = stamp
        images = []
        for cap in self._caps:
            ok, image = cap.retrieve()
            if not ok or image is None:
                return None
            images.append(image)
        return images, stamps[0], t_host_ns

    def _frame(self, images: list[np.ndarray], t_device_ns: int, t_host_ns: int) -> StereoFrame:
        if self.side_by_side:
            half = images[0].shape[1] // 2
            left, right = images[0][:, :half], images[0][:, half : 2 * half]
        else:
            left, right = images
        if self._seq is None:
            seq = 0
        else:
            seq = self._seq + max(1, round((t_device_ns - self._last_t_ns) / self.period_ns))
        self._seq, self._last_t_ns = seq, t_device_ns
        return StereoFrame(
            left=np.ascontiguousarray(left),
            right=np.ascontiguousarray(right),
            seq=seq,
            t_device_ns=int(t_device_ns),
            t_host_ns=int(t_host_ns),
        )
