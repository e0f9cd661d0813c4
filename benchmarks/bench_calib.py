"""Calibration accuracy against the simulated bench's truth, and calibration time for N views.

Corners: per image set (OpenCV's stereo sample as shipped, shrunk and blurred, darkened with
noise and JPEG; 1080p endoscope renders with soft optics), vbfe's stereo calibration beside each
plain OpenCV pipeline (tests/plain_opencv.py: cornerSubPix half 5, 8, 11 and the sector detector
with ACCURACY): pairs kept, RMS left / right / stereo, |T|, seconds per view, and vbfe's RMS and
|T| as ratios to the best plain pipeline's (on renders, f and B errors against the truth).

Stereo: for each N, several seeds of N rendered views at random poses (640×360, rig with lens
distortion); prints the worst relative error of fx, fy, cx, cy (both cameras) and of B, the
stereo RMS, and the solve time (corner detection + calibrations), also as a ratio to the time of
detecting the board in one image measured in the same run. Projector: Gray-code captures at
P poses; prints the relative error of the projector's fx, fy, cx, cy and of its translation.
SD endoscope (vbfe.truth.endoscope: 640×480, fx/fy = 1.1, principal points 90 px apart, 6 mm
baseline, dim and noisy; 9×6 and 7×7 boards; then as issue 56's labs measured theirs: fx/fy 1.05,
85 px apart, k1 -0.3, eyes 0.7° apart): vbfe's `calibrate stereo FOLDER` as a user runs
it beside plain OpenCV (findChessboardCorners + cornerSubPix 11×11, calibrateCamera per eye,
stereoCalibrate with the intrinsics as a guess) on the same images: worst error of f (fx, fy),
of cx, cy (px) and of B, stereo RMS, views used, rectified f; beside each joint solve the same
tool with each eye's intrinsics fixed from half as many other views, at least 8 (vbfe:
`calibrate camera` per eye, then `calibrate stereo --intrinsics`; OpenCV: calibrateCamera,
then stereoCalibrate with CALIB_FIX_INTRINSIC), with its f and B as ratios to that tool's joint
solve.
Run: ``python -m benchmarks.bench_calib [--sets sharp dark] [--views 10 20 30] [--seeds 3]
[--poses 8] [--endoscope-views 20] [--endoscope-only]`` (``--sets`` alone: the corner table only).
"""

from __future__ import annotations

import argparse
import functools
import tempfile
import time
from collections.abc import Callable

import numpy as np

from benchmarks import smoke
from tests import calib_image_sets as image_sets
from tests import plain_opencv
from vbfe.calib.board import BoardDetector, BoardSpec
from vbfe.calib.commands import projector_capture
from vbfe.calib.gates import GateLimits
from vbfe.calib.projector import calibrate_projector, load_captures
from vbfe.calib.stereo import StereoOptions, calibrate_stereo
from vbfe.calib.views import ViewSet
from vbfe.drivers.sim.board_scene import DISTANCE_M
from vbfe.drivers.sim.charuco_scene import random_board_poses, render_board_views
from vbfe.drivers.sim.rig import StereoRig, default_rig
from vbfe.rig_config import builtin_rig
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


def _truth_errors(K1, K2, B: float, rig) -> tuple[float, float, float]:
    """Worst |f / f_true - 1| (fx, fy, both eyes), worst |c - c_true| (px), |B / B_true - 1|."""
    f_err = max(
        abs(K[i, i] / cam.K[i, i] - 1)
        for K, cam in ((K1, rig.left), (K2, rig.right))
        for i in (0, 1)
    )
    c_err = max(
        float(np.abs(K[:2, 2] - cam.K[:2, 2]).max()) for K, cam in ((K1, rig.left), (K2, rig.right))
    )
    return f_err, c_err, abs(B / rig.baseline_m - 1)


def _plain_corners(folder, inner: tuple[int, int]) -> dict[str, list]:
    """findChessboardCorners + cornerSubPix 11x11 in the pairs both eyes see whole."""
    import cv2

    subpix = (cv2.TERM_CRITERIA_MAX_ITER + cv2.TERM_CRITERIA_EPS, 30, 0.01)
    corners: dict[str, list] = {"left": [], "right": []}
    for left in sorted((folder / "left").iterdir()):
        right = folder / "right" / left.name.replace("left", "right")
        found = []
        for path in (left, right):
            grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            ok, c = cv2.findChessboardCorners(
                grey, inner, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
            )
            found.append(cv2.cornerSubPix(grey, c, (5, 5), (-1, -1), subpix) if ok else None)
        if all(c is not None for c in found):
            corners["left"].append(found[0])
            corners["right"].append(found[1])
    return corners


def plain_opencv_stereo(folder, inner: tuple[int, int], square_m: float, rig, intrinsics_from=None):
    """Plain OpenCV on an endoscope folder: (errors, stereo RMS, views used, rectified f, B);
    with ``intrinsics_from`` (another folder) each eye's intrinsics are calibrated on that
    folder's views and fixed (``CALIB_FIX_INTRINSIC``)."""
    import cv2

    obj = np.zeros((inner[0] * inner[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0 : inner[0], 0 : inner[1]].T.reshape(-1, 2) * square_m
    corners = _plain_corners(folder, inner)
    own = corners if intrinsics_from is None else _plain_corners(intrinsics_from, inner)
    size = (640, 480)
    _, K1, D1, _, _ = cv2.calibrateCamera([obj] * len(own["left"]), own["left"], size, None, None)
    _, K2, D2, _, _ = cv2.calibrateCamera([obj] * len(own["right"]), own["right"], size, None, None)
    n = len(corners["left"])
    flags = cv2.CALIB_USE_INTRINSIC_GUESS if intrinsics_from is None else cv2.CALIB_FIX_INTRINSIC
    rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
        [obj] * n, corners["left"], corners["right"], K1, D1, K2, D2, size, flags=flags
    )
    _, _, P1, P2, _, _, _ = cv2.stereoRectify(K1, D1, K2, D2, size, R, T)
    B = float(-P2[0, 3] / P2[0, 0])
    return _truth_errors(K1, K2, B, rig), float(rms), n, float(P1[0, 0]), B


def _vbfe_rows(folder, weak, name: str, rig, tmp) -> list[tuple]:
    """vbfe's joint solve and its fixed-intrinsics solve (each eye's `calibrate camera` on the
    weaker views of ``weak``), as a user runs them: (tool, errors, RMS, views, f, B) or
    (tool, exit code) when refused."""
    import contextlib
    import io

    from vbfe.calib.calibration import load_calibration
    from vbfe.cli.main import main as vbfe

    board = ["--inner-corners", name, "--square-mm", "3"]
    quiet = io.StringIO()

    def run(*args) -> int:
        with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
            return vbfe([*map(str, args), *board])

    rows: list[tuple] = []
    cameras = [tmp / "left.yaml", tmp / "right.yaml"]
    solves = {"vbfe": [], "fixed": ["--intrinsics", *cameras]}
    for eye, camera in zip(("left", "right"), cameras, strict=True):
        if run("calibrate", "camera", weak, "--eye", eye, "-o", camera) != 0:
            solves.pop("fixed")
            rows.append(("fixed", "camera refused"))
            break
    for tool, extra in solves.items():
        out = tmp / f"{tool}.yaml"
        code = run("calibrate", "stereo", folder, "-o", out, "--no-report", *extra)
        if code != 0:
            rows.append(
                (tool, f"refused (exit {code}): {quiet.getvalue().strip().splitlines()[-1]}")
            )
            continue
        cal = load_calibration(out)
        errors = _truth_errors(cal.K1, cal.K2, cal.B, rig)
        rows.append((tool, errors, cal.rms_stereo_px, len(cal.info["views"]), cal.f, cal.B))
    return rows


def endoscope_rows(n_views: int, seeds: int, barrel: bool = False) -> None:
    """Print vbfe (the CLI with the board options only; joint and with each eye's intrinsics
    fixed from `calibrate camera` on half as many other views, at least 8) beside plain OpenCV
    (joint and FIX_INTRINSIC) on SD endoscope renders, per board and seed; f and B also as
    ratios to the same tool's joint solve."""
    from pathlib import Path

    from vbfe.truth.endoscope import (
        barrel_endoscope_rig,
        sd_endoscope_rig,
        write_sd_endoscope_views,
    )

    true_rig = barrel_endoscope_rig() if barrel else sd_endoscope_rig()
    print(
        f"\nSD endoscope ({n_views} views, 640x480, "
        + (
            "fx/fy 1.05, cx 85 px apart, k1 -0.3, eyes 0.7 deg apart"
            if barrel
            else "fx/fy 1.1, cx 90 px apart"
        )
        + ", B 6 mm, dim)"
    )
    print(
        f"{'board':>5} {'seed':>4} {'tool':>12} {'max df/f':>9} {'max dc px':>9} {'dB/B':>7} "
        f"{'RMS px':>7} {'views':>5} {'rect f':>7} {'f/joint':>8} {'B/joint':>8}"
    )
    for inner in ((9, 6), (7, 7)):
        name = f"{inner[0]}x{inner[1]}"
        for seed in range(seeds):
            with tempfile.TemporaryDirectory() as tmp:
                folder, weak = Path(tmp) / "views", Path(tmp) / "weak"
                rig = write_sd_endoscope_views(
                    folder, inner, 3.0, n_views, seed=300 + seed, rig=true_rig
                )
                write_sd_endoscope_views(
                    weak, inner, 3.0, max(8, n_views // 2), seed=600 + seed, rig=true_rig
                )
                rows = _vbfe_rows(folder, weak, name, rig, Path(tmp))
                rows.append(("opencv", *plain_opencv_stereo(folder, inner, 3e-3, rig)))
                rows.append(("opencv fixed", *plain_opencv_stereo(folder, inner, 3e-3, rig, weak)))
                joint = {"vbfe": None, "fixed": None, "opencv": None, "opencv fixed": None}
                for row in rows:
                    if len(row) > 2:
                        joint[row[0]] = row
                for row in rows:
                    if len(row) == 2:
                        print(f"{name:>5} {seed:>4} {row[0]:>12} {row[1]}")
                        continue
                    tool, (f_err, c_err, b_err), rms, n, f, B = row
                    base = joint["vbfe" if tool in ("vbfe", "fixed") else "opencv"]
                    ratios = (
                        f"{f / base[4]:>8.4f} {B / base[5]:>8.4f}" if base else f"{'-':>8} {'-':>8}"
                    )
                    print(
                        f"{name:>5} {seed:>4} {tool:>12} {f_err * 100:>8.3f}% {c_err:>9.2f} "
                        f"{b_err * 100:>6.3f}% {rms:>7.3f} {n:>5} {f:>7.1f} {ratios}"
                    )


CornerSet = tuple[Callable[[], image_sets.Pairs], tuple[int, int], float, StereoRig | None]
# name -> (the pairs, inner corners, square side in mm, the true rig of a render or None); the
# endoscope renders: 12 pairs (seed 0) and the slow test's 8 (seed 3)
CORNER_SETS: dict[str, CornerSet] = {
    "sharp": (image_sets.sharp, image_sets.INNER, image_sets.SQUARE_MM, None),
    "shrunk": (image_sets.shrunk, image_sets.INNER, image_sets.SQUARE_MM, None),
    "dark": (image_sets.dark, image_sets.INNER, image_sets.SQUARE_MM, None),
    "endoscope": (
        functools.partial(image_sets.endoscope, n=12, seed=0),
        image_sets.ENDOSCOPE_INNER,
        image_sets.ENDOSCOPE_SQUARE_MM,
        image_sets.endoscope_rig(),
    ),
    "endoscope-test": (  # the set of tests/calib/test_calib_corner_choice.py
        functools.partial(image_sets.endoscope, n=8, seed=3),
        image_sets.ENDOSCOPE_INNER,
        image_sets.ENDOSCOPE_SQUARE_MM,
        image_sets.endoscope_rig(),
    ),
}


def corner_table(name: str, corner_set: CornerSet) -> None:
    """vbfe and every plain OpenCV pipeline on one set, one row each."""
    make, inner, square_mm, rig = corner_set
    pairs = make()
    spec = BoardSpec(
        squares_x=inner[0] + 1,
        squares_y=inner[1] + 1,
        square_m=square_mm * 1e-3,
        target="chessboard",
    )
    views = ViewSet(list(pairs), [f"v{i:02d}" for i in range(len(pairs))], name)
    start = time.perf_counter()
    result = calibrate_stereo(views, spec, StereoOptions(gates=GateLimits(nominal_baseline_m=0)))
    vbfe_s = (time.perf_counter() - start) / len(pairs)
    cal = result.calibration
    rows = [
        (
            "vbfe",
            len(result.names),
            cal.rms_left_px,
            cal.rms_right_px,
            cal.rms_stereo_px,
            float(np.linalg.norm(cal.T)),
            vbfe_s,
        )
    ]
    results = {}
    for pipeline in plain_opencv.PIPELINES:
        start = time.perf_counter()
        r = plain_opencv.stereo(pairs, inner, square_mm * 1e-3, pipeline)
        results[pipeline] = r
        seconds = (time.perf_counter() - start) / len(pairs)
        rows.append((pipeline, r.n_pairs, r.rms_left, r.rms_right, r.rms, r.T_norm, seconds))
    best_name, best = plain_opencv.best(results)
    print(f"\n{name}: {len(pairs)} pairs, {inner[0]}x{inner[1]} corners")
    print(
        f"{'':>12} {'pairs':>5} {'RMS left':>8} {'right':>6} {'stereo':>6} {'|T| mm':>8} "
        f"{'s/view':>7}"
    )
    for label, n, rl, rr, rs, t, seconds in rows:
        print(
            f"{label:>12} {n:>5} {rl:>8.3f} {rr:>6.3f} {rs:>6.3f} {t * 1e3:>8.4f} {seconds:>7.2f}"
        )
    print(
        f"vbfe / best plain ({best_name}): RMS {cal.rms_stereo_px / best.rms:.3f}x, "
        f"|T| {np.linalg.norm(cal.T) / best.T_norm - 1:+.3%}; "
        + ", ".join(f"{k} {v}" for k, v in cal.info["views_per_detector"]["method"].items())
    )
    if rig is not None:
        f_err = max(
            abs(K[i, i] / camera.K[i, i] - 1)
            for K, camera in ((cal.K1, rig.left), (cal.K2, rig.right))
            for i in (0, 1)
        )
        b_err = abs(cal.B / rig.baseline_m - 1)
        print(f"vs truth: max |df|/f (fx, fy) {f_err:.4%}, |dB|/B {b_err:.4%}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sets",
        nargs="*",
        choices=list(CORNER_SETS),
        default=None,
        help="corner sets (default all); given alone, only the corner table",
    )
    parser.add_argument("--views", type=int, nargs="+", default=[10, 20, 30])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--poses", type=int, default=8, help="projector poses (0: skip)")
    parser.add_argument(
        "--endoscope-views", type=int, default=20, help="SD endoscope views per set (0: skip)"
    )
    parser.add_argument(
        "--endoscope-only", action="store_true", help="only the SD endoscope tables"
    )
    args = smoke.parse(parser, argv, views=[8], seeds=1, poses=0, endoscope_views=0)
    if args.endoscope_only:
        endoscope_rows(args.endoscope_views, args.seeds)
        endoscope_rows(args.endoscope_views, args.seeds, barrel=True)
        return
    print("corners: vbfe beside plain OpenCV pipelines")
    for name in args.sets or list(CORNER_SETS)[: 1 if args.smoke else None]:
        corner_table(name, CORNER_SETS[name])
    if args.sets:
        return
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
            config = board_config(builtin_rig(), on_a_stand=True, fps=10.0, seed=200 + seed)
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

    if args.endoscope_views:
        endoscope_rows(args.endoscope_views, args.seeds)
        endoscope_rows(args.endoscope_views, args.seeds, barrel=True)


if __name__ == "__main__":
    main()
