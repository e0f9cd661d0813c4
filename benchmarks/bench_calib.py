"""Calibration accuracy against the simulated bench's truth, and calibration time for N views.

Stereo: for each N, several seeds of N rendered views at random poses (640×360, rig with lens
distortion); prints the worst relative error of fx, fy, cx, cy (both cameras) and of B, the
stereo RMS, and the solve time (corner detection + calibrations), also as a ratio to the time of
detecting the board in one image measured in the same run. Projector: Gray-code captures at
P poses; prints the relative error of the projector's fx, fy, cx, cy and of its translation.
Run: ``python -m benchmarks.bench_calib [--views 10 20 30] [--seeds 3] [--poses 8]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from vbfe.calib.board import BoardDetector, BoardSpec
from vbfe.calib.commands import projector_capture
from vbfe.calib.projector import calibrate_projector, load_captures
from vbfe.calib.stereo import calibrate_stereo
from vbfe.calib.views import ViewSet
from vbfe.common.config import load_config
from vbfe.drivers.sim.board_scene import DISTANCE_M
from vbfe.drivers.sim.charuco_scene import random_board_poses, render_board_views
from vbfe.drivers.sim.rig import default_rig
from vbfe.truth import board_config, calibration_from_rig


def intrinsic_errors(K: np.ndarray, K_true: np.ndarray) -> np.ndarray:
    """Relative errors of fx, fy, cx, cy."""
    idx = ((0, 0), (1, 1), (0, 2), (1, 2))
    return np.array([abs(K[i] / K_true[i] - 1) for i in idx])


def detect_reference_s(spec: BoardSpec, image: np.ndarray, repeats: int = 10) -> float:
    """Seconds to find the board in one image (the unit the solve time is expressed in)."""
    detector = BoardDetector(spec)
    start = time.perf_counter()
    for _ in range(repeats):
        detector.detect(image)
    return (time.perf_counter() - start) / repeats


def stereo_rows(rig, spec: BoardSpec, n_views: int, seeds: int):
    """(worst intrinsic error, B error, stereo RMS, seconds) per seed."""
    board = spec.board()
    for seed in range(seeds):
        rng = np.random.default_rng(100 + seed)
        poses = random_board_poses(n_views, rng, distance_m=DISTANCE_M, rig=rig, board=board)
        views = ViewSet(
            render_board_views(rig, board, poses, rng=rng),
            [f"v{i}" for i in range(n_views)],
            "bench",
        )
        start = time.perf_counter()
        cal = calibrate_stereo(views, spec).calibration
        seconds = time.perf_counter() - start
        worst = max(
            intrinsic_errors(cal.K1, rig.left.K).max(), intrinsic_errors(cal.K2, rig.right.K).max()
        )
        yield views, worst, abs(cal.B / rig.baseline_m - 1), cal.rms_stereo_px, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, nargs="+", default=[10, 20, 30])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--poses", type=int, default=8, help="projector poses (0: skip)")
    args = parser.parse_args()
    rig = default_rig(640, 360, distortion=True)
    spec = BoardSpec()

    print("stereo calibration vs truth (640x360, distortion), worst over both cameras")
    print(
        f"{'views':>5} {'seed':>4} {'max |dK|/K':>10} {'|dB|/B':>8} {'RMS px':>7} "
        f"{'solve s':>8} {'x detect':>8}"
    )
    reference = None
    for n in args.views:
        for seed, (views, worst, b_err, rms, seconds) in enumerate(
            stereo_rows(rig, spec, n, args.seeds)
        ):
            if reference is None:
                reference = detect_reference_s(spec, views.pairs[0][0])
                print(f"(reference: one board detection = {reference * 1e3:.1f} ms)")
            print(
                f"{n:>5} {seed:>4} {worst * 100:>9.3f}% {b_err * 100:>7.3f}% {rms:>7.3f} "
                f"{seconds:>8.2f} {seconds / reference:>8.0f}"
            )

    if args.poses:
        print(f"\nprojector calibration vs truth, {args.poses} Gray-code poses")
        camera = calibration_from_rig(rig)
        size = (rig.projector.width, rig.projector.height)
        for seed in range(args.seeds):
            start = time.perf_counter()
            config = board_config(load_config(None), on_a_stand=True, fps=10.0, seed=200 + seed)
            with tempfile.TemporaryDirectory() as folder:
                projector_capture(config, folder, args.poses)
                captures = load_captures(folder)
            render_s = time.perf_counter() - start
            start = time.perf_counter()
            result = calibrate_projector(captures, spec, camera, size)
            solve_s = time.perf_counter() - start
            errors = intrinsic_errors(result.K, rig.projector.K) * 100
            t_err = np.linalg.norm(result.T - rig.T_proj) * 1e3
            print(
                f"seed {seed}: fx {errors[0]:.2f}%  fy {errors[1]:.2f}%  cx {errors[2]:.2f}%  "
                f"cy {errors[3]:.2f}%  |dT| {t_err:.3f} mm  RMS {result.rms_px:.2f} px  "
                f"render {render_s:.1f} s  solve {solve_s:.1f} s "
                f"({solve_s / reference:.0f} x detect)"
            )


if __name__ == "__main__":
    main()
