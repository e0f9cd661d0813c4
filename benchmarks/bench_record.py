"""Recording throughput per image codec: stereo at 30 fps + 1 kHz force, at 640x360 and 1080p.

For each frame size and storage it prints
  * writer-only speed: how many times faster than real time SessionWriter stores the streams
    (same batching as the recorder), as a ratio to a plain ``file.write`` of the same raw bytes
    measured in the same run, the CPU time per stereo frame, and the real-time factor one free
    core gives at that CPU time ("1 core": what a busy machine cannot change);
  * a real-time recording through the Recorder (threads, queues, SWMR flushes) with paced
    devices: frames stored and dropped, CPU per frame (all threads), MB per second of
    recording and the compression ratio;
  * read speed: stereo frames per second read back (decompressed) by h5py;
  * who can read the images: "stock HDF5" (MATLAB, HDFView, h5dump, any h5py), "with plugin"
    (hdf5plugin's filters, HDF5_PLUGIN_PATH) or "h5py only".
``--busy N`` runs N busy processes beside every measurement (a shared lab machine).
``mjpeg-reencode`` is the ``mjpeg`` storage fed decoded frames (as the OpenCV backend gives):
every frame is JPEG-encoded on the way in. ``mjpeg-passthrough`` is the ``mjpeg`` storage fed
the camera's own JPEG bytes (as the linuxpy V4L2 backend gives, :class:`JpegStereoFrame`, never
decoded): written as they are. Frames are pre-generated (structured-light pattern + sensor
noise), so synthesis does not count.

    python -m benchmarks.bench_record [--seconds 20] [--sizes 640x360 1920x1080] [--busy 1]
        [--storages gzip lzf mjpeg-passthrough ...]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from benchmarks import smoke
from vbfe.acquire import Recorder, SessionReader, SessionWriter
from vbfe.acquire.session.layout import COMPRESSIONS, DEFAULT_COMPRESSION, IMAGE_CODECS
from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.pacing import sleep_until
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.rig import Rig
from vbfe.drivers.samples import ForceSample, JpegStereoFrame, StereoFrame
from vbfe.drivers.trocar.base import ForceSensor

FPS, FORCE_HZ = 30.0, 1000.0
STORAGES = {name: (name, False) for name in COMPRESSIONS if name != "mjpeg"}
STORAGES.update({"mjpeg-reencode": ("mjpeg", False), "mjpeg-passthrough": ("mjpeg", True)})


def make_frames(
    size: tuple[int, int], n: int = 8, seed: int = 0
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Stereo pairs that look like the endoscope's view: pattern on a shaded surface + noise."""
    width, height = size
    rng = np.random.default_rng(seed)
    pattern = make_pattern(width, height).astype(np.float32)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    frames = []
    for k in range(n):
        shade = 0.5 + 0.4 * np.cos((xx - width / 2 - 20 * k) / width * 3) * np.cos(
            (yy - height / 2) / height * 2
        )
        pair = []
        for shift in (0.0, 12.0):
            m = np.float32([[1, 0, shift + 3 * k], [0, 1, 0]])
            lit = cv2.warpAffine(pattern, m, (width, height), borderMode=cv2.BORDER_REFLECT)
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
        self.height, self.width = frames[0][0].shape[:2]
        self.fps = FPS
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
    height, width = frames[0][0].shape[:2]
    start, cpu_start = time.perf_counter(), time.process_time()
    writer = SessionWriter(path, (width, height), compression)
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
    return elapsed, cpu


def read_fps(path: Path) -> float:
    """Stereo frames per second read back as images (decompressed, or JPEG-decoded) through
    :class:`SessionReader`."""
    with SessionReader(path) as reader:
        start = time.perf_counter()
        n = sum(1 for _ in reader.iter_frames())
        return n / max(time.perf_counter() - start, 1e-9)


def recorder_run(
    folder: Path, compression: str, frames: list, encoded: list | None, seconds: float
) -> dict:
    """A real-time recording through the Recorder; returns counts, drops, CPU, size and the
    read-back speed."""
    path = folder / f"rec-{compression}.h5"
    devices = Rig(PregeneratedCamera(frames, encoded), PacedForce(), NullProjector())
    rec = Recorder(devices, path, compression=compression, min_free_bytes=0)
    cpu_start = time.process_time()
    rec.start()
    stats = rec.run(seconds)
    cpu = time.process_time() - cpu_start
    size = path.stat().st_size
    reads = read_fps(path)
    path.unlink()
    return {
        "frames": stats.frames,
        "samples": stats.samples,
        "dropped": stats.dropped,
        "cpu_ms_per_frame": 1e3 * cpu / max(stats.frames, 1),
        "mb_per_s": size / 1e6 / seconds,
        "ratio": stats.frames * frames[0][0].nbytes * 2 / max(size, 1),
        "read_fps": reads,
    }


@contextlib.contextmanager
def busy_processes(n: int) -> Iterator[None]:
    """``n`` processes spinning a core each while the block runs."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(max(n, 0))]
    try:
        yield
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()


def bench_size(size: tuple[int, int], storages: list[str], seconds: float, folder: Path) -> None:
    """Every storage at one frame size (see the module docstring for the columns)."""
    frames = make_frames(size)
    encoded = [
        tuple(
            cv2.imencode(".jpg", eye, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes() for eye in pair
        )
        for pair in frames
    ]
    n_frames = int(seconds * FPS)
    width, height = size
    ref = reference_write_s(folder, frames, n_frames)
    print(
        f"{width}x{height} RGB stereo at 30 fps ({width * height * 6 * FPS / 1e6:.0f} MB/s "
        f"raw) + force at 1 kHz, {seconds:g} s; plain file.write: {seconds / ref:.2f}x real time"
    )
    print(
        f"{'storage':<17} {'writer x rt':>11} {'vs write':>8} {'CPU ms/fr':>9} {'1 core':>6} "
        f"{'rec frames':>10} {'dropped':>7} {'rec CPU ms/fr':>13} {'MB/s rec':>8} "
        f"{'ratio':>5} {'read fr/s':>9}  readable by"
    )
    for storage in storages:
        compression, passthrough = STORAGES[storage]
        jpegs = encoded if passthrough else None
        w, w_cpu = writer_only_s(folder, compression, frames, jpegs, n_frames)
        (folder / f"writer-{compression}.h5").unlink()
        r = recorder_run(folder, compression, frames, jpegs, seconds)
        dropped = sum(r["dropped"].values()) if isinstance(r["dropped"], dict) else r["dropped"]
        default = " (default)" if compression == DEFAULT_COMPRESSION else ""
        print(
            f"{storage:<17} {seconds / w:>10.2f}x {ref / w:>7.2f}x {1e3 * w_cpu / n_frames:>9.1f} "
            f"{n_frames / FPS / max(w_cpu, 1e-9):>5.1f}x "
            f"{r['frames']:>10} {dropped:>7} {r['cpu_ms_per_frame']:>13.1f} "
            f"{r['mb_per_s']:>8.1f} {r['ratio']:>4.1f}x {r['read_fps']:>9.0f}  "
            f"{IMAGE_CODECS[compression].reach}{default}",
            flush=True,
        )


def _size(text: str) -> tuple[int, int]:
    width, height = text.lower().split("x")
    return int(width), int(height)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--sizes", nargs="+", type=_size, default=[(640, 360), (1920, 1080)])
    parser.add_argument("--storages", nargs="+", default=list(STORAGES), choices=list(STORAGES))
    parser.add_argument("--busy", type=int, default=1, help="busy processes beside (default 1)")
    parser.add_argument("--dir", default=None, help="where to write (default: a temp dir)")
    args = smoke.parse(parser, argv, seconds=0.5, sizes=[(320, 180)], storages=["lzf"], busy=0)
    print(
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} before, "
        f"{args.busy} busy process(es) beside"
    )
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp, busy_processes(args.busy):
        for size in args.sizes:
            bench_size(size, args.storages, args.seconds, Path(tmp))


if __name__ == "__main__":
    main()
