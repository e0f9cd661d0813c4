"""Driver overheads: trocar decoding and camera frame handling against the bare libraries.

Trocar: CanTrocar.read (checksum, cantools decode, counter unwrap, stats) on N queued TRF85D
frames on a python-can virtual bus, against bare ``bus.recv`` of the same frames, same run.
Camera: OpenCVStereoCamera.read (grab thread, queue, split and copy of the eyes, drop detection)
on a fake side-by-side capture returning a pre-rendered image, against calling that capture's
grab/retrieve directly. Prints throughput and ratios;
the trocar must keep up with 1 kHz with a wide margin, the camera with 30 fps.
Run from the repository root (it uses the test fakes): ``python -m benchmarks.bench_drivers``.
"""

from __future__ import annotations

import argparse
import time

import can
import numpy as np

from benchmarks import smoke
from tests.fakes.camera import FakeStereoCapture, render_eye
from vbfe.drivers.camera.opencv import OpenCVStereoCamera
from vbfe.drivers.trocar.can_trocar import CanTrocar
from vbfe.drivers.trocar.dbc import load_frame_format


def queue_frames(channel: str, n: int) -> None:
    """Send ``n`` valid TRF85D frames on a virtual channel (the reader must already be open)."""
    fmt = load_frame_format()
    with can.Bus(interface="virtual", channel=channel) as sender:
        for i in range(n):
            sender.send(
                can.Message(
                    arbitration_id=fmt.frame_id,
                    is_extended_id=False,
                    data=fmt.encode(np.array([0.1, -0.2, i * 1e-3 % 5]), i),
                )
            )


def trocar_rates(n: int) -> tuple[float, float]:
    """(bare recv, CanTrocar.read) frames per second."""
    with can.Bus(interface="virtual", channel="bench-raw") as bus:
        queue_frames("bench-raw", n)
        start = time.perf_counter()
        while bus.recv(timeout=0) is not None:
            pass
        raw = n / (time.perf_counter() - start)
    with CanTrocar(interface="virtual", channel="bench-trocar") as trocar:
        queue_frames("bench-trocar", n)
        start = time.perf_counter()
        while trocar.read(timeout_s=0) is not None:
            pass
        driver = n / (time.perf_counter() - start)
    return raw, driver


class PrerenderedCapture(FakeStereoCapture):
    """The fake capture with one image rendered up front, so only the driver's work is timed."""

    def __init__(self, width: int, height: int, n_frames: int) -> None:
        super().__init__(width, height, n_frames=n_frames, realtime=False)
        self._image = np.hstack([render_eye(width, height, 0), render_eye(width, height, 0, 4)])

    def retrieve(self) -> tuple[bool, np.ndarray | None]:
        return True, self._image


def camera_rates(n: int, width: int, height: int) -> tuple[float, float]:
    """(bare capture grab/retrieve, OpenCVStereoCamera.read) frames per second."""
    capture = PrerenderedCapture(width, height, n)
    start = time.perf_counter()
    while capture.grab():
        capture.retrieve()
    raw = n / (time.perf_counter() - start)
    capture = PrerenderedCapture(width, height, n)
    with OpenCVStereoCamera(
        device="bench", width=width, height=height, capture_factory=lambda dev: capture
    ) as camera:
        start = time.perf_counter()
        for _ in range(n):
            camera.read(timeout_s=1.0)
        driver = n / (time.perf_counter() - start)
    return raw, driver


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20000, help="trocar frames (default 20000)")
    args = smoke.parse(parser, argv, frames=500)
    raw, driver = trocar_rates(args.frames)
    print(
        f"trocar: bare recv {raw:9.0f} frames/s   CanTrocar.read {driver:9.0f} frames/s   "
        f"ratio {raw / driver:5.2f}   margin over 1 kHz: {driver / 1000:5.1f}x"
    )
    for width, height in ((640, 360), (1920, 1080)):
        raw, driver = camera_rates(300, width, height)
        print(
            f"camera {width}x{height}/eye: bare capture {raw:7.1f} fps   "
            f"OpenCVStereoCamera.read {driver:7.1f} fps   ratio {raw / driver:5.2f}   "
            f"margin over 30 fps: {driver / 30:5.1f}x"
        )


if __name__ == "__main__":
    main()
