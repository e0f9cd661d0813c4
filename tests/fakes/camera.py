"""A fake V4L2 stereo endoscope: an object with the ``cv2.VideoCapture`` surface.

It produces synthetic side-by-side frames (a moving bar, the right eye shifted by a fixed
disparity) stamped with a device clock, and can drop frames, run out, or vanish. Every frame
carries its sensor sequence number in pixel (0, 0) of each eye: blue = low byte, green = high.
``FakeStereoCamera`` is the real :class:`OpenCVStereoCamera` driving this fake.
"""

from __future__ import annotations

import time
from collections.abc import Iterable

import cv2
import numpy as np

from vbfe.drivers.camera.opencv import OpenCVStereoCamera
from vbfe.drivers.pacing import sleep_until

DISPARITY_PX = 4
DEVICE_CLOCK_BASE_NS = 1_000_000_000_000  # device time of frame 0 when not paced in real time


def frame_seq(image: np.ndarray) -> int:
    """The sensor sequence number the fake wrote into pixel (0, 0) of an eye."""
    return int(image[0, 0, 0]) | int(image[0, 0, 1]) << 8


def render_eye(width: int, height: int, seq: int, shift_px: int = 0) -> np.ndarray:
    """One eye's view of frame ``seq``: a gradient with a bar moving 3 px per frame.

    Pixel ``x`` shows the scene at ``x + shift_px``, so an eye rendered with ``shift_px = d``
    sees everything ``d`` pixels further left (a disparity of ``d``).
    """
    x_scene = np.arange(width) + shift_px
    row = (40 + 120 * x_scene / max(width - 1, 1)).clip(0, 255)
    bar = (x_scene - seq * 3 - width // 4) % (2 * width) < max(2, width // 16)
    row = np.where(bar, 255, row).astype(np.uint8)
    image = np.repeat(np.repeat(row[None, :, None], height, axis=0), 3, axis=2)
    image[0, 0] = (seq & 0xFF, (seq >> 8) & 0xFF, 0)
    return image


class FakeStereoCapture:
    """Stands in for ``cv2.VideoCapture(dev, cv2.CAP_V4L2)`` of a stereo endoscope.

    ``eye`` is ``"both"`` (side-by-side, ``2*width`` wide), ``"left"`` or ``"right"``. The
    sensor makes frames ``0..n_frames-1`` at ``fps``; ``drop_seqs`` never reach the reader; after
    ``disconnect_after`` delivered frames the device vanishes. With ``realtime`` the fake paces
    frames on the host clock and loses the oldest when the reader is more than ``n_buffers``
    frames behind, as the kernel does; otherwise frames come as fast as they are read.
    """

    def __init__(
        self,
        width: int,
        height: int,
        fps: float = 30.0,
        n_frames: int | None = None,
        drop_seqs: Iterable[int] = (),
        disconnect_after: int | None = None,
        clock_offset_ns: int = 0,
        clock_drift_ppm: float = 0.0,
        realtime: bool = True,
        eye: str = "both",
        n_buffers: int = 4,
    ) -> None:
        self.width, self.height, self.fps, self.eye = width, height, float(fps), eye
        self.n_frames, self.drop_seqs = n_frames, frozenset(drop_seqs)
        self.disconnect_after, self.realtime, self.n_buffers = disconnect_after, realtime, n_buffers
        self.clock_offset_ns, self.clock_drift_ppm = clock_offset_ns, clock_drift_ppm
        self.props: dict[int, float] = {}
        self.delivered = 0
        self.kernel_dropped: list[int] = []
        self._opened = True
        self._next_seq = 0
        self._seq: int | None = None
        self._host_start_ns = time.monotonic_ns()

    @property
    def period_ns(self) -> float:
        return 1e9 / self.fps

    def _device_ns(self, seq: int) -> int:
        base = self._host_start_ns if self.realtime else DEVICE_CLOCK_BASE_NS
        return int(base + self.clock_offset_ns + round(seq * self.period_ns))

    def _host_due_ns(self, seq: int) -> int:
        return self._host_start_ns + round(seq * self.period_ns / (1 + self.clock_drift_ppm * 1e-6))

    def isOpened(self) -> bool:  # noqa: N802 - cv2.VideoCapture's name
        return self._opened

    def grab(self) -> bool:
        if not self._opened:
            return False
        if self.disconnect_after is not None and self.delivered >= self.disconnect_after:
            self._opened = False
            return False
        while self._next_seq in self.drop_seqs:
            self._next_seq += 1
        if self.n_frames is not None and self._next_seq >= self.n_frames:
            time.sleep(self.period_ns * 1e-9)
            return False
        if self.realtime:
            behind = (time.monotonic_ns() - self._host_due_ns(self._next_seq)) // self.period_ns
            if behind > self.n_buffers:
                lost = int(behind) - self.n_buffers
                self.kernel_dropped.extend(range(self._next_seq, self._next_seq + lost))
                self._next_seq += lost
            sleep_until(self._host_due_ns(self._next_seq))
        self._seq, self._next_seq = self._next_seq, self._next_seq + 1
        self.delivered += 1
        return True

    def retrieve(self) -> tuple[bool, np.ndarray | None]:
        if self._seq is None or not self._opened:
            return False, None
        left = render_eye(self.width, self.height, self._seq)
        right = render_eye(self.width, self.height, self._seq, shift_px=DISPARITY_PX)
        image = {"both": np.hstack([left, right]), "left": left, "right": right}[self.eye]
        return True, image

    def read(self) -> tuple[bool, np.ndarray | None]:
        return self.retrieve() if self.grab() else (False, None)

    def get(self, prop: int) -> float:
        if prop == cv2.CAP_PROP_FRAME_WIDTH:
            return float(2 * self.width if self.eye == "both" else self.width)
        if prop == cv2.CAP_PROP_FRAME_HEIGHT:
            return float(self.height)
        if prop == cv2.CAP_PROP_FPS:
            return self.fps
        if prop == cv2.CAP_PROP_POS_MSEC:
            return 0.0 if self._seq is None else self._device_ns(self._seq) / 1e6
        return self.props.get(prop, 0.0)

    def set(self, prop: int, value: float) -> bool:
        self.props[prop] = value  # one fixed mode: size and rate requests change nothing
        return True

    def release(self) -> None:
        self._opened = False


class FakeStereoCamera(OpenCVStereoCamera):
    """The real V4L2 driver reading a side-by-side :class:`FakeStereoCapture` in real time."""

    def __init__(
        self,
        width: int = 64,
        height: int = 48,
        fps: float = 30.0,
        n_frames: int | None = None,
        drop_seqs: Iterable[int] = (),
        disconnect_after: int | None = None,
        clock_offset_ns: int = 0,
        clock_drift_ppm: float = 0.0,
        n_buffers: int = 4,
    ) -> None:
        self.captures: list[FakeStereoCapture] = []

        def factory(device: str | int) -> FakeStereoCapture:
            capture = FakeStereoCapture(
                width,
                height,
                fps,
                n_frames,
                drop_seqs,
                disconnect_after,
                clock_offset_ns,
                clock_drift_ppm,
                n_buffers=n_buffers,
            )
            self.captures.append(capture)
            return capture

        super().__init__(
            device="fake-endoscope",
            width=width,
            height=height,
            fps=fps,
            fourcc="YUYV",
            capture_factory=factory,
        )
