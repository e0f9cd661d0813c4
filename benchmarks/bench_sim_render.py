"""Rendering speed of the simulated bench.

Prints, for 1280×720 and the default 640×360: stereo pairs per second of the ray caster with the
De Bruijn pattern on the deforming tissue, and of a full bench camera read (mechanics + tissue
grid + render), each also as a multiple of the time of one ``cv2.remap`` of a same-size BGR
image measured in the same run. Recording a 30 fps session needs ≥ 10 camera reads per second.

    python -m benchmarks.bench_sim_render
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from functools import partial

import cv2
import numpy as np

from benchmarks import smoke
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.sim import SimBench
from vbfe.drivers.sim.mechanics import TissueSample, TractionProtocol, Trial
from vbfe.drivers.sim.render import StereoRenderer
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, UniformAlbedo


def seconds_per_call(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls (after one warm-up call)."""
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def reference_remap(width: int, height: int) -> float:
    """One bilinear cv2.remap of a width×height BGR uint8 image (the unit of the ratios)."""
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    map_x = rng.uniform(0, width - 1, (height, width)).astype(np.float32)
    map_y = rng.uniform(0, height - 1, (height, width)).astype(np.float32)
    map_x.sort(axis=1)
    map_y.sort(axis=0)
    return seconds_per_call(lambda: cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR), 20)


def _render_next(
    renderer: StereoRenderer, tissue: TissueSurface, trial: Trial, times: Iterator[float]
) -> None:
    renderer.render(tissue.with_load(trial.at(next(times))[0]))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["1280x720", "640x360"], metavar="WxH")
    args = smoke.parse(parser, argv, sizes=["320x180"])
    for size in args.sizes:
        width, height = (int(v) for v in size.lower().split("x"))
        unit = reference_remap(width, height)
        rig = default_rig(width, height)
        renderer = StereoRenderer(rig, rng=np.random.default_rng(0))
        renderer.set_pattern(make_pattern(rig.projector.width, rig.projector.height))
        trial = Trial(TractionProtocol(), TissueSample.random(np.random.default_rng(1)))
        tissue = TissueSurface(texture=UniformAlbedo())
        times = iter(np.linspace(1.0, 8.0, 1000))
        render = seconds_per_call(partial(_render_next, renderer, tissue, trial, times), 10)
        bench = SimBench(width=width, height=height)
        with bench.camera() as camera:
            read = seconds_per_call(camera.read, 10)
        print(f"{width}x{height}: reference cv2.remap {unit * 1e3:.1f} ms")
        print(
            f"  render stereo pair (deforming tissue + pattern): {1 / render:6.1f} pairs/s "
            f"= {render / unit:5.1f} x remap"
        )
        print(
            f"  bench camera read (mechanics + render):         {1 / read:6.1f} frames/s "
            f"= {read / unit:5.1f} x remap  ({'≥' if read <= 0.1 else '<'} 10 fps)"
        )


if __name__ == "__main__":
    main()
