"""Recording throughput: 1920×1080 RGB stereo at 30 fps + 1 kHz force, per frame storage.

For each storage it prints
  * writer-only speed: how many times faster than real time SessionWriter stores the streams
    (same batching as the recorder), and that as a ratio to a plain ``file.write`` of the same
    raw bytes measured in the same run, plus the CPU time per stereo frame;
  * a real-time recording through the Recorder (threads, queues, SWMR flushes) with paced
    devices: frames and samples stored, drops, CPU per frame (all threads), file size and
    compression ratio.
``mjpeg-reencode`` is the ``mjpeg`` storage fed decoded frames (as the OpenCV backend gives):
every frame is JPEG-encoded on the way in. ``mjpeg-passthrough`` is the ``mjpeg`` storage fed
the camera's own JPEG bytes (as the linuxpy V4L2 backend gives, :class:`JpegStereoFrame`, never
decoded): written as they are. Frames are pre-generated (structured-light pattern + sensor
noise), so synthesis does not count.

    python benchmarks/bench_record.py [--seconds 20] [--storages lzf mjpeg-passthrough ...]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from vbfe.acquire import Recorder, SessionWriter
from vbfe.acquire.session.layout import COMPRESSIONS
from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.pacing import sleep_until
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.rig import Rig
from vbfe.drivers.samples import ForceSample, JpegStereoFrame, StereoFrame
from vbfe.drivers.trocar.base import ForceSensor

WIDTH, HEIGHT, FPS, FORCE_HZ = 1920, 1080, 30.0, 1000.0
STORAGES = {name: (name, False) for name in COMPRESSIONS if name != "mjpeg"}
STORAGES.update({"mjpeg-reencode": ("mjpeg", False), "mjpeg-passthrough": ("mjpeg", True)})


def make_frames(n: int = 8, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Stereo pairs that look like the endoscope's view: pattern on a shaded surface + noise."""
    rng = np.random.default_rng(seed)
    pattern = make_pattern(WIDTH, HEIGHT).astype(np.float32)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    frames = []
    for k in range(n):
        shade = 0.5 + 0.4 * np.cos((xx - WIDTH / 2 - 20 * k) / WIDTH * 3) * np.cos(
            (yy - HEIGHT / 2) / HEIGHT * 2
        )
        pair = []
        for shift in (0.0, 12.0):
            m = np.float32([[1, 0, shift + 3 * k], [0, 1, 0]])
            lit = cv2.warpAffine(pattern, m, (WIDTH, HEIGHT), borderMode=cv2.BORDER_REFLECT)
            image = lit * shade[..., None] + rng.normal(0, 2.0, lit.shape).astype(np.float32)
            pair.append(np.clip(image, 0, 255).astype(np.uint8))
        frames.append(tuple(pair))
    return frames


def wait_due(t0_ns: int, seq: int, rate_hz: float, timeout_s: float) -> int | None:
    """Sleep until sample ``seq`` of a ``rate_hz`` stream started at ``t0_ns`` is due; returns
    its due time, or None when that is more than ``timeout_s`` away."""
    due = t0_ns + int(seq * 1e9 / rate_hz)
    return due if sleep_until(due, timeout_s) else None


class PregeneratedCamera(StereoCamera):
    """Plays pre-generated pairs at ``fps`` in real time."""

    def __init__(
        self, frames: list[tuple[np.ndarray, np.ndarray]], encoded: list | None = None
    ) -> None:
        super().__init__()
        self.frames, self.encoded = frames, encoded
        self.width, self.height, self.fps = WIDTH, HEIGHT, FPS
        self._seq, self._t0 = 0, 0

    def _open(self) -> None:
        self._t0 = time.monotonic_ns()

    def _read_sample(self, timeout_s: float) -> StereoFrame | None:
        due = wait_due(self._t0, self._seq, self.fps, timeout_s)
        if due is None:
            return None
        if self.encoded:  # the camera's own JPEG bytes, as the V4L2 backend delivers them
            frame: StereoFrame = JpegStereoFrame(
                self.encoded[self._seq % len(self.encoded)], self._seq, due, time.monotonic_ns()
            )
        else:
            left, right = self.frames[self._seq % len(self.frames)]
            frame = StereoFrame(left, right, self._seq, due, time.monotonic_ns())
        self._seq += 1
        return frame

    def _close(self) -> None:
        pass


class PacedForce(ForceSensor):
    """1 kHz force samples in real time."""

    rate_hz = FORCE_HZ

    def __init__(self) -> None:
        super().__init__()
        self._seq, self._t0 = 0, 0

    def _open(self) -> None:
        self._t0 = time.monotonic_ns()

    def _read_sample(self, timeout_s: float) -> ForceSample | None:
        due = wait_due(self._t0, self._seq, self.rate_hz, timeout_s)
        if due is None:
            return None
        sample = ForceSample(
            np.array([0.0, 0.0, self._seq * 1e-4]), self._seq, due, time.monotonic_ns()
        )
        self._seq += 1
        return sample

    def _close(self) -> None:
        pass


class NullProjector(Projector):
    width, height = 64, 48

    def _open(self) -> None:
        pass

    def _show(self, pattern: np.ndarray, name: str, seq: int) -> int:
        return -1

    def _close(self) -> None:
        pass


def reference_write_s(folder: Path, frames: list, n_frames: int) -> float:
    """Seconds to write the same raw frame bytes with plain ``file.write`` (+ fsync)."""
    path = folder / "raw.bin"
    start = time.perf_counter()
    with open(path, "wb") as f:
        for i in range(n_frames):
            left, right = frames[i % len(frames)]
            f.write(left.data)
            f.write(right.data)
    elapsed = time.perf_counter() - start
    path.unlink()
    return elapsed


def writer_only_s(
    folder: Path, compression: str, frames: list, encoded: list | None, n_frames: int
) -> tuple[float, float]:
    """Seconds (wall, CPU) SessionWriter needs to store ``n_frames`` frames and their force
    samples; ``encoded`` given: frames are the camera's JPEG bytes."""
    path = folder / f"writer-{compression}.h5"
    per_frame = int(FORCE_HZ / FPS)
    start, cpu_start = time.perf_counter(), time.process_time()
    writer = SessionWriter(path, (WIDTH, HEIGHT), compression)
    for i in range(n_frames):
        if encoded:
            frame: StereoFrame = JpegStereoFrame(encoded[i % len(encoded)], i, i, i)
        else:
            frame = StereoFrame(*frames[i % len(frames)], i, i, i)
        writer.append_frames([frame])
        writer.append_forces(
            [ForceSample(np.zeros(3), i * per_frame + j, 0, 0) for j in range(per_frame)]
        )
        if i % int(FPS) == 0:
            writer.flush()
    writer.close()
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    path.unlink()
    return elapsed, cpu


def recorder_run(
    folder: Path, compression: str, frames: list, encoded: list | None, seconds: float
) -> dict:
    """A real-time recording through the Recorder; returns counts, drops, CPU and size."""
    path = folder / f"rec-{compression}.h5"
    devices = Rig(PregeneratedCamera(frames, encoded), PacedForce(), NullProjector())
    rec = Recorder(devices, path, compression=compression, min_free_bytes=0)
    cpu_start = time.process_time()
    rec.start()
    stats = rec.run(seconds)
    cpu = time.process_time() - cpu_start
    size = path.stat().st_size
    path.unlink()
    return {
        "frames": stats.frames,
        "samples": stats.samples,
        "dropped": stats.dropped,
        "cpu_ms_per_frame": 1e3 * cpu / max(stats.frames, 1),
        "size_mb": size / 1e6,
        "raw_mb": stats.frames * WIDTH * HEIGHT * 6 / 1e6,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--storages", nargs="+", default=list(STORAGES), choices=list(STORAGES))
    parser.add_argument("--dir", default=None, help="where to write (default: a temp dir)")
    args = parser.parse_args()
    frames = make_frames()
    encoded = [
        tuple(
            cv2.imencode(".jpg", eye, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes() for eye in pair
        )
        for pair in frames
    ]
    n_frames = int(args.seconds * FPS)
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        folder = Path(tmp)
        ref = reference_write_s(folder, frames, n_frames)
        print(
            f"{args.seconds:g} s of 1920x1080 RGB stereo at 30 fps "
            f"({WIDTH * HEIGHT * 6 * FPS / 1e6:.0f} MB/s raw) + force at 1 kHz"
        )
        print(f"reference: plain file.write of the raw frames: {args.seconds / ref:.2f}x real time")
        print(
            f"{'storage':<17} {'writer x realtime':>17} {'vs file.write':>13} "
            f"{'writer CPU ms/fr':>16} {'rec frames':>10} {'dropped':>24} "
            f"{'rec CPU ms/fr':>13} {'size MB':>8} {'ratio':>6}"
        )
        for storage in args.storages:
            compression, passthrough = STORAGES[storage]
            jpegs = encoded if passthrough else None
            w, w_cpu = writer_only_s(folder, compression, frames, jpegs, n_frames)
            r = recorder_run(folder, compression, frames, jpegs, args.seconds)
            print(
                f"{storage:<17} {args.seconds / w:>16.2f}x {ref / w:>12.2f}x "
                f"{1e3 * w_cpu / n_frames:>16.1f} {r['frames']:>10} {str(r['dropped']):>24} "
                f"{r['cpu_ms_per_frame']:>13.1f} {r['size_mb']:>8.0f} "
                f"{r['raw_mb'] / max(r['size_mb'], 1e-9):>5.1f}x",
                flush=True,
            )


if __name__ == "__main__":
    main()
