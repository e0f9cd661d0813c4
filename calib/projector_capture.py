"""Gray-code captures for projector calibration, through the camera and projector drivers.

For each board pose the projector shows white, black and the Gray-code sequence
(:func:`~vbfe.calib.projector.projector_images`), and the left camera image of each is kept once
it can show it: the first frame that arrived at least ``settle_s`` after the projector reported
the pattern shown (both stamps on the host clock). Between poses the board is moved: a pose is
captured when the camera sees a new scene that has come to rest (frame-to-frame change below
``still_level``), and discarded when the white image after the sequence shows that the board
moved during it. Each pose is written as it is done (``pose_NNN/``, the folder
:func:`~vbfe.calib.projector.load_captures` reads, plus ``frames.json``: which camera frame was
kept for each pattern and when it was shown), so an interrupted capture loses nothing.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vbfe.calib.options import CalibOptions, calib_field
from vbfe.calib.projector import GrayCodeCapture, projector_images, save_captures
from vbfe.common.errors import CalibrationError
from vbfe.drivers.camera.base import FrameSource
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.samples import StereoFrame

SIZE_FILE = "projector.json"  # the projector size the captures were made for
FRAMES_FILE = "frames.json"  # per pose: the frame kept for each pattern
MAX_DISCARDS = 3  # sequences in a row spoilt by a moving board before the capture gives up


@dataclass
class GrayCaptureOptions(CalibOptions):
    """How the capture waits for patterns and poses (defaults: the ``[calib]`` table)."""

    settle_s: float = calib_field("projector_settle_s")  # projector latency + one exposure
    still_level: float = calib_field("projector_still_level")  # |grey change| of a board at rest
    change_level: float = calib_field("projector_change_level")  # |grey change| of a new pose
    still_frames: int = calib_field("projector_still_frames")  # frames at rest before capturing
    pose_timeout_s: float = calib_field("projector_pose_timeout_s")  # longest wait for a pose
    read_timeout_s: float = 2.0  # longest wait for one camera frame


def _grey(frame: StereoFrame) -> np.ndarray:
    left = frame.left
    return left if left.ndim == 2 else cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)


def _change(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute grey-level difference of two images at quarter resolution."""
    small = [
        cv2.resize(
            x, (max(x.shape[1] // 4, 1), max(x.shape[0] // 4, 1)), interpolation=cv2.INTER_AREA
        ).astype(np.int16)
        for x in (a, b)
    ]
    return float(np.abs(small[0] - small[1]).mean())


class GrayCodeCapturer:
    """Shows patterns on ``projector`` and keeps what ``camera`` sees (both open)."""

    def __init__(
        self, camera: FrameSource, projector: Projector, options: GrayCaptureOptions | None = None
    ) -> None:
        self.camera, self.projector = camera, projector
        self.options = options or GrayCaptureOptions()
        self.white, self.black, self.patterns = projector_images(self.projector_size)
        self.log: list[dict[str, int | str]] = []  # the frames shoot() kept

    @property
    def projector_size(self) -> tuple[int, int]:
        """Width and height of the projector in pixels."""
        return int(self.projector.width), int(self.projector.height)

    def _read(self, after_ns: int = 0) -> StereoFrame:
        frame = self.camera.read_after(after_ns, self.options.read_timeout_s)
        if frame is None:
            raise CalibrationError(
                f"the camera gave no frame within "
                f"{self.options.read_timeout_s} s; check it is streaming"
            )
        return frame

    def shoot(self, image: np.ndarray, name: str) -> StereoFrame:
        """Show ``image`` and return the first frame that arrived ``settle_s`` after it."""
        event = self.projector.show(image, name)
        frame = self._read(event.t_host_ns + int(round(self.options.settle_s * 1e9)))
        self.log.append(
            {
                "pattern": name,
                "shown_t_host_ns": event.t_host_ns,
                "frame_seq": frame.seq,
                "frame_t_host_ns": frame.t_host_ns,
            }
        )
        return frame

    def wait_for_pose(self, previous: np.ndarray | None) -> np.ndarray:
        """Under white light, wait until the board rests at a pose unlike ``previous`` (the last
        pose's white image; ``None``: any pose); returns the white image there."""
        o = self.options
        last = _grey(self.shoot(self.white, "white"))
        start_ns = None
        moved, still = previous is None, 0
        while True:
            frame = self._read()
            start_ns = frame.t_host_ns if start_ns is None else start_ns
            grey = _grey(frame)
            moved = moved or (previous is not None and _change(grey, previous) >= o.change_level)
            still = still + 1 if _change(grey, last) < o.still_level else 0
            last = grey
            if moved and still >= o.still_frames:
                return grey
            if frame.t_host_ns - start_ns > o.pose_timeout_s * 1e9:
                raise CalibrationError(
                    f"the board did not come to rest at a new pose within {o.pose_timeout_s} s "
                    "(set [calib] projector_pose_timeout_s to wait longer); the poses captured "
                    "so far are kept"
                )

    def capture_pose(self) -> GrayCodeCapture | None:
        """White, black and the Gray-code sequence at the current pose; ``None`` when the white
        image after the sequence shows the board moved. :attr:`log` holds its frames."""
        self.log = []
        shots = [_grey(self.shoot(self.white, "white")), _grey(self.shoot(self.black, "black"))]
        shots += [_grey(self.shoot(p, f"gray_{k:02d}")) for k, p in enumerate(self.patterns)]
        after = _grey(self.shoot(self.white, "white"))
        if _change(after, shots[0]) >= self.options.still_level:
            return None
        return GrayCodeCapture(shots[0], shots[1], shots[2:])


def existing_poses(folder: Path) -> int:
    """Number of ``pose_NNN`` folders already in ``folder``."""
    return len([p for p in folder.glob("pose_*") if p.is_dir()]) if folder.is_dir() else 0


def capture_gray_code(
    camera: FrameSource,
    projector: Projector,
    folder: str | Path,
    n_poses: int,
    options: GrayCaptureOptions | None = None,
    on_event: Callable[[str], None] | None = None,
) -> list[Path]:
    """Capture ``n_poses`` new poses into ``folder`` (after any already there) through an open
    camera and projector; returns the pose folders written. ``on_event(message)`` is told what
    the capture waits for and what it kept."""
    if n_poses < 1:
        raise CalibrationError(f"--poses must be at least 1, got {n_poses}")
    folder = Path(folder)
    tell = on_event or (lambda message: None)
    capturer = GrayCodeCapturer(camera, projector, options)
    size = capturer.projector_size
    stored = captured_projector_size(folder)
    if stored is not None and stored != size:
        raise CalibrationError(
            f"{folder} holds captures for a {stored[0]}x{stored[1]} projector "
            f"but this one is {size[0]}x{size[1]}; use a new folder"
        )
    folder.mkdir(parents=True, exist_ok=True)
    (folder / SIZE_FILE).write_text(json.dumps({"size": list(size)}))
    first = existing_poses(folder)
    written: list[Path] = []
    previous, discarded = None, 0
    while len(written) < n_poses:
        tell(
            f"pose {len(written) + 1}/{n_poses}: move the board to a new pose inside the "
            "projected area and hold it still"
        )
        previous = capturer.wait_for_pose(previous)
        capture = capturer.capture_pose()
        if capture is None:
            discarded += 1
            if discarded == MAX_DISCARDS:
                raise CalibrationError(
                    f"the board moved during {MAX_DISCARDS} Gray-code "
                    "sequences in a row; fix it on a stand (the poses "
                    "captured so far are kept)"
                )
            tell("the board moved during the sequence: pose discarded, hold it still")
            continue
        discarded = 0
        index = first + len(written)
        save_captures(folder, [capture], start=index)
        written.append(folder / f"pose_{index:03d}")
        (written[-1] / FRAMES_FILE).write_text(json.dumps(capturer.log, indent=1))
        tell(f"kept {written[-1]}")
    return written


def captured_projector_size(folder: str | Path) -> tuple[int, int] | None:
    """The projector size :func:`capture_gray_code` recorded in ``folder`` (``None``: none)."""
    path = Path(folder) / SIZE_FILE
    if not path.is_file():
        return None
    try:
        width, height = json.loads(path.read_text())["size"]
        return int(width), int(height)
    except (ValueError, KeyError, TypeError):
        raise CalibrationError(
            f"{path} is not a projector size file; delete it or set "
            "[calib] projector_width and projector_height"
        ) from None
