"""Per-frame cost of the texture feature (``estimate/texture_motion.py``) on ``vbfe live``'s
clouds, against the numpy reference it replaced (``tests/texture_reference.py``), in one run.

Frames of the textured bench at 640×360 are rendered, reconstructed as ``vbfe live`` does at
the ``[live]`` scale and row scale, and the peak texture displacement of each is computed by
both paths, alternating frame by frame (the machine is shared: the ratio is what counts).
Prints the median milliseconds per frame of each, their ratio, the largest relative
difference of the feature (goal: under 2 %) and the load average. Run: ``python -m
benchmarks.bench_texture_speed [--frames 30] [--size 640x360]``.
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

from benchmarks import smoke
from benchmarks.bench_live import rendered_frames
from tests.texture_reference import reference_peak
from vbfe.estimate.texture_motion import TextureMotion
from vbfe.recon import Reconstructor
from vbfe.rig_config import builtin_rig
from vbfe.truth import calibration_from_rig, true_rig


def live_clouds(size: tuple[int, int], n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(points, colours) of ``n`` textured bench frames reconstructed as ``vbfe live`` does."""
    config = builtin_rig({"bench": dict(width=size[0], height=size[1], textured=True)})
    settings = config.live
    calibration = calibration_from_rig(true_rig(config)).scaled(
        settings.scale, settings.scale * settings.row_scale
    )
    reconstructor = Reconstructor(calibration, config.sgbm)
    clouds = []
    for frame in rendered_frames(config, n):
        left, right = np.hsplit(frame, 2)
        left, right = (
            cv2.resize(image, calibration.image_size, interpolation=cv2.INTER_AREA)
            for image in (left, right)
        )
        cloud = reconstructor.process(left, right)
        clouds.append((cloud.points, cloud.colors))
    return clouds


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--size", default="640x360")
    args = smoke.parse(parser, argv, frames=3, size="320x180")
    size = tuple(int(v) for v in args.size.split("x"))
    clouds = live_clouds((size[0], size[1]), args.frames)
    rest = clouds[0]
    motion, reason = TextureMotion.from_rest(*rest)
    if motion is None:
        raise SystemExit(f"the bench's rest cloud is not tracked: {reason}")
    motion.peak_displacement_m(*clouds[1])  # compiles the grid loop (cached after)
    seconds: dict[str, list[float]] = {"reference": [], "fast": []}
    values: dict[str, list[float]] = {"reference": [], "fast": []}
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    for points, colors in clouds[1:]:
        for name in ("reference", "fast"):
            start = time.perf_counter()
            value = (
                reference_peak(*rest, points, colors)
                if name == "reference"
                else motion.peak_displacement_m(points, colors)
            )
            seconds[name].append(time.perf_counter() - start)
            values[name].append(value)
    reference, fast = (np.median(seconds[n]) * 1e3 for n in ("reference", "fast"))
    difference = np.abs(np.subtract(values["fast"], values["reference"])) / np.array(
        values["reference"]
    )
    print(
        f"texture feature at {args.size}, {len(clouds) - 1} frames: reference "
        f"{reference:.1f} ms, fast {fast:.1f} ms per frame "
        f"(median), {reference / fast:.2f}x; feature {np.median(values['fast']) * 1e3:.3f} mm "
        f"median, largest difference {difference.max():.2%} (goal < 2 %); load average "
        f"{os.getloadavg()[0]:.2f} at the end"
    )


if __name__ == "__main__":
    main()
