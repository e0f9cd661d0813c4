"""Reconstruction speed and accuracy on a rendered tissue pair (1280×720 and 640×360).

Prints, per size, the time per frame of the full pipeline (rectify, SGBM, De Bruijn
verification, triangulation) next to bare OpenCV StereoSGBM with the same settings on the same
pair, measured in the same run (goal: ratio ≤ 1.15, wall time and CPU time of one thread), the
per-stage CPU profile, then the accuracy against the rendered truth with and without
verification (and of the verified points alone). Run:
``python -m benchmarks.bench_recon [--repeats N] [--sizes 1280x720 640x360]``.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import cv2
import numpy as np

from benchmarks import smoke
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.recon import Reconstructor, kernels, make_pattern
from vbfe.recon.matching import sgbm_disparity
from vbfe.recon.verify import coded_grid, verify_disparity
from vbfe.rig_config import builtin_rig
from vbfe.truth import calibration_from_rig, evaluate_against_truth

WORKING_DISTANCE_M = 0.06


def elapsed_s(fn: Callable[[], object], clock: Callable[[], float] = time.perf_counter) -> float:
    """Time of one call of ``fn`` on ``clock`` (wall time by default)."""
    start = clock()
    fn()
    return clock() - start


def timings_s(
    runs: dict[str, Callable[[], object]], repeats: int, clock: Callable[[], float]
) -> dict[str, float]:
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
    for name, label in (
        ("sgbm", "bare cv2.StereoSGBM.compute"),
        ("bare", "pipeline without verification"),
        ("full", "pipeline with verification"),
    ):
        goal = "   (goal <= 1.15x)" if name == "full" else ""
        print(f"  {label:32s} {t[name] * 1e3:8.1f} ms   {t[name] / t['sgbm']:.2f}x{goal}")


def stage_profile(
    reconstructor: Reconstructor, left: np.ndarray, right: np.ndarray, repeats: int
) -> dict[str, float]:
    """Median one-thread CPU time (s) of each stage of the verified pipeline."""
    rect_left, rect_right = reconstructor.rectify(left, right)
    decoder, params = reconstructor.decoder, reconstructor.searched
    matcher = params.create(3)  # the reconstructor's matcher, made from the same settings
    left_code = decoder.decode(rect_left)
    right_code = decoder.decode(rect_right, period_px=left_code.period_px)
    disparity = sgbm_disparity(rect_left, rect_right, params, matcher)
    verified, status, _ = verify_disparity(
        disparity, left_code, right_code, params.verify_search_px
    )
    cal = reconstructor.calibration
    stages = {
        "rectify": lambda: reconstructor.rectify(left, right),
        "sgbm (+ fixed-point to px)": lambda: sgbm_disparity(
            rect_left, rect_right, params, matcher
        ),
        "decode left": lambda: decoder.decode(rect_left),
        "decode right": lambda: decoder.decode(rect_right, period_px=left_code.period_px),
        "coded region": lambda: coded_grid(left_code),
        "verify": lambda: verify_disparity(
            disparity, left_code, right_code, params.verify_search_px
        ),
        "triangulate": lambda: kernels.triangulate(
            verified.copy(), status.copy(), rect_left, cal.f, cal.B, cal.cx, cal.cy, 0.0, cal.fy
        ),
    }
    return timings_s(stages, repeats, time.thread_time)


def bench_size(width: int, height: int, repeats: int) -> None:
    """Timings, profile and accuracy at one frame size."""
    rig = default_rig(width, height, working_distance_m=WORKING_DISTANCE_M)
    rng = np.random.default_rng(0)
    surface = TissueSurface(distance_m=WORKING_DISTANCE_M, texture=tissue_texture(rng))
    pair = render_scene(
        rig, surface, make_pattern(rig.projector.width, rig.projector.height), rng=rng
    )
    calibration = calibration_from_rig(rig)
    params, settings = builtin_rig().sgbm, builtin_rig().recon
    verified = Reconstructor(calibration, params, verify=True, settings=settings)
    bare = Reconstructor(calibration, params, verify=False, settings=settings)
    matcher = verified.params.create(3)  # the same (derived) disparity range
    print(
        f"== frame {width}x{height}, disparity range {verified.params.min_disparity}.."
        f"{verified.params.min_disparity + verified.params.num_disparities - 1} px, "
        f"{repeats} repeats (median), load {os.getloadavg()[0]:.1f}"
    )
    runs = {
        "sgbm": lambda: matcher.compute(pair.left, pair.right),
        "full": lambda: verified.process(pair.left, pair.right),
        "bare": lambda: bare.process(pair.left, pair.right),
    }
    print_ratios(
        f"wall time, OpenCV threads as configured ({cv2.getNumThreads()}):",
        timings_s(runs, repeats, time.perf_counter),
    )
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # everything in this thread: its CPU time ignores other processes' load
    print_ratios(
        "CPU time of one thread (OpenCV single-threaded, as in session workers):",
        timings_s(runs, repeats, time.thread_time),
    )
    profile = stage_profile(verified, pair.left, pair.right, repeats)
    cv2.setNumThreads(threads)
    total = sum(profile.values())
    print("per-stage CPU time of one thread (verified pipeline):")
    for name, seconds in profile.items():
        print(f"  {name:32s} {seconds * 1e3:8.2f} ms  {seconds / total:6.1%}")

    truth = (pair.disparity_left_px, pair.depth_left_m, pair.valid_left)
    print(
        f"accuracy against the rendered truth (working distance {WORKING_DISTANCE_M * 1e3:.0f} mm)"
    )
    cloud = verified.process(pair.left, pair.right)
    only_verified = np.where(cloud.status >= kernels.KEPT, cloud.disparity, np.nan)
    for name, estimate in (
        ("SGBM only", bare.process(pair.left, pair.right)),
        ("SGBM + De Bruijn", cloud),
        ("  verified points", only_verified),
    ):
        report = evaluate_against_truth(
            estimate, *truth, f_px=calibration.f, baseline_m=calibration.B
        )
        print(
            f"  {name:17s} valid {report.valid_fraction:6.1%}   median |dz| "
            f"{report.median_abs_depth_error_m * 1e3:.3f} mm "
            f"({report.median_abs_depth_error_m / WORKING_DISTANCE_M:.2%})   p95 |dz| "
            f"{report.p95_abs_depth_error_m * 1e3:.3f} mm   bad pixels (>1 px) "
            f"{report.bad_pixel_rate:.3%}"
        )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--sizes", nargs="+", default=["1280x720", "640x360"], metavar="WxH")
    args = smoke.parse(parser, argv, repeats=1, sizes=["640x360"])
    for size in args.sizes:
        width, height = (int(v) for v in size.lower().split("x"))
        bench_size(width, height, args.repeats)


if __name__ == "__main__":
    main()
