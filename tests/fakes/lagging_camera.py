"""A camera fault: from some frame on, every frame carries the images of the frame before.

Wraps any stereo camera; frames keep their own sequence numbers and timestamps, so the clock
fit sees nothing wrong while the picture is one frame period late: a one-frame latency jump,
as when a capture queue grows by one buffer. A frame whose predecessor the wrapped camera
never delivered (a starved simulator skips frames) is withheld too, a device-side drop, so the
picture is always exactly one frame period late.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from vbfe.drivers.samples import StereoFrame


class LaggingCamera:
    """Delegates to ``camera``; frames with ``seq >= from_seq`` show the previous frame."""

    def __init__(self, camera: Any, from_seq: int) -> None:
        self._camera, self.from_seq = camera, from_seq
        self._previous: StereoFrame | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._camera, name)

    def read(self, timeout_s: float = 1.0) -> StereoFrame | None:
        """The wrapped camera's next frame, with the previous frame's images once lagging."""
        while True:
            frame = self._camera.read(timeout_s)
            if frame is None:
                return None
            if frame.seq < self.from_seq:
                self._previous = frame
                return frame
            previous, self._previous = self._previous, frame
            if previous is not None and previous.seq == frame.seq - 1:
                return replace(frame, left=previous.left, right=previous.right)
