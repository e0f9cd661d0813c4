"""Reconstruction speed and accuracy on a rendered 1280×720 tissue pair.

Prints the time per frame of the full pipeline (rectify, SGBM, De Bruijn verification,
triangulation) next to bare OpenCV StereoSGBM with the same settings on the same pair, measured
in the same run (goal: ratio ≤ 1.3), then the accuracy against the rendered truth with and
without verification. Run: ``python benchmarks/bench_recon.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from vbfe.config import default_config, section
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.recon import (Reconstructor, SgbmParams, calibration_from_rig, evaluate_against_truth,
                        make_pattern)

WORKING_DISTANCE_M = 0.06


def median_time_s(fn: Callable[[], object], repeats: int) -> float:
    """Median wall time of ``fn`` over ``repeats`` calls (after one warm-up call)."""
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    args = parser.parse_args()

    rig = default_rig(args.width, args.height, working_distance_m=WORKING_DISTANCE_M)
    rng = np.random.default_rng(0)
    surface = TissueSurface(distance_m=WORKING_DISTANCE_M, texture=tissue_texture(rng))
    pair = render_scene(rig, surface, make_pattern(rig.projector.width, rig.projector.height),
                        rng=rng)
    calibration = calibration_from_rig(rig)
    params = SgbmParams.from_config(section(default_config(), "sgbm"))
    matcher = params.create(3)
    verified = Reconstructor(calibration, params, verify=True)
    bare = Reconstructor(calibration, params, verify=False)

    # interleave the measurements so machine load affects both alike
    t_sgbm, t_full, t_bare = [], [], []
    for _ in range(args.repeats):
        t_sgbm.append(median_time_s(lambda: matcher.compute(pair.left, pair.right), 1))
        t_full.append(median_time_s(lambda: verified.process(pair.left, pair.right), 1))
        t_bare.append(median_time_s(lambda: bare.process(pair.left, pair.right), 1))
    sgbm_s, full_s, bare_s = (float(np.median(t)) for t in (t_sgbm, t_full, t_bare))
    print(f"frame {args.width}x{args.height}, {args.repeats} repeats (median)")
    print(f"  bare cv2.StereoSGBM.compute     {sgbm_s * 1e3:8.1f} ms   1.00x")
    print(f"  pipeline without verification   {bare_s * 1e3:8.1f} ms   {bare_s / sgbm_s:.2f}x")
    print(f"  pipeline with verification      {full_s * 1e3:8.1f} ms   {full_s / sgbm_s:.2f}x"
          f"   (goal <= 1.30x)")

    truth = (pair.disparity_left_px, pair.depth_left_m, pair.valid_left)
    print("accuracy against the rendered truth (working distance "
          f"{WORKING_DISTANCE_M * 1e3:.0f} mm)")
    for name, reconstructor in (("SGBM only", bare), ("SGBM + De Bruijn", verified)):
        report = evaluate_against_truth(reconstructor.process(pair.left, pair.right), *truth)
        print(f"  {name:17s} valid {report.valid_fraction:6.1%}   median |dz| "
              f"{report.median_abs_depth_error_m * 1e3:.3f} mm "
              f"({report.median_abs_depth_error_m / WORKING_DISTANCE_M:.2%})   p95 |dz| "
              f"{report.p95_abs_depth_error_m * 1e3:.3f} mm   bad pixels (>1 px) "
              f"{report.bad_pixel_rate:.3%}")


if __name__ == "__main__":
    main()
