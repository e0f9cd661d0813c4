"""Reconstruction speed and accuracy on a rendered 1280×720 tissue pair.

Prints the time per frame of the full pipeline (rectify, SGBM, De Bruijn verification,
triangulation) next to bare OpenCV StereoSGBM with the same settings on the same pair, measured
in the same run (goal: ratio ≤ 1.15), then the accuracy against the rendered truth with and
without verification. Run: ``python benchmarks/bench_recon.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import cv2
import numpy as np

from vbfe.config import default_config, section
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.recon import Reconstructor, SgbmParams, make_pattern
from vbfe.recon.quality import ReconSettings
from vbfe.truth import calibration_from_rig, evaluate_against_truth

WORKING_DISTANCE_M = 0.06


def elapsed_s(fn: Callable[[], object], clock: Callable[[], float] = time.perf_counter) -> float:
    """Time of one call of ``fn`` on ``clock`` (wall time by default)."""
    start = clock()
    fn()
    return clock() - start


def timings_s(runs: dict[str, Callable[[], object]], repeats: int,
              clock: Callable[[], float]) -> dict[str, float]:
    """Median time of each run, the runs interleaved so machine load affects all alike."""
    for fn in runs.values():  # warm-up
        fn()
    times: dict[str, list[float]] = {name: [] for name in runs}
    for _ in range(repeats):
        for name, fn in runs.items():
            times[name].append(elapsed_s(fn, clock))
    return {name: float(np.median(t)) for name, t in times.items()}


def print_ratios(title: str, t: dict[str, float]) -> None:
    """The three timings and their ratios to bare SGBM."""
    print(title)
    for name, label in (("sgbm", "bare cv2.StereoSGBM.compute"),
                        ("bare", "pipeline without verification"),
                        ("full", "pipeline with verification")):
        goal = "   (goal <= 1.15x)" if name == "full" else ""
        print(f"  {label:32s} {t[name] * 1e3:8.1f} ms   {t[name] / t['sgbm']:.2f}x{goal}")


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
    settings = ReconSettings.from_config(section(default_config(), "recon"))
    verified = Reconstructor(calibration, params, verify=True, settings=settings)
    bare = Reconstructor(calibration, params, verify=False, settings=settings)
    matcher = verified.params.create(3)  # the same (derived) disparity range
    print(f"disparity range {verified.params.min_disparity}.."
          f"{verified.params.min_disparity + verified.params.num_disparities - 1} px")

    runs = {"sgbm": lambda: matcher.compute(pair.left, pair.right),
            "full": lambda: verified.process(pair.left, pair.right),
            "bare": lambda: bare.process(pair.left, pair.right)}
    print(f"frame {args.width}x{args.height}, {args.repeats} repeats (median)")
    print_ratios("wall time, OpenCV threads as configured:",
                 timings_s(runs, args.repeats, time.perf_counter))
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # everything in this thread: its CPU time ignores other processes' load
    print_ratios("CPU time of one thread (OpenCV single-threaded, as in session workers):",
                 timings_s(runs, args.repeats, time.thread_time))
    cv2.setNumThreads(threads)

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
