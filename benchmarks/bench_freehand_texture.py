"""Does tracking the tissue's texture recover the sideways part of a freehand pull?

Textured freehand trials (demo size: 640×360 at 10 fps, 15 s; seeds as the demo's freehand
trials, ``FREEHAND_FIRST_SEED + r``) are recorded through the public API on the simulated bench
(``textured = true``) and reconstructed with the true calibration; recordings are kept in
``--sessions`` and reused. Per frame, against the trial's first frame:

- depth only: the peak depth change (``estimate/displacement.py``, what Hooke reads today);
- texture: the peak 3D displacement from optical flow on the clouds' colours
  (``estimate/texture_motion.py``).

Printed per trial: each measure's gain and residual sd against the bench's true visible
displacement (3D, and its depth component for the depth-only measure), then Hooke's law
(``F = k̂·d``, one slope over the training trials) on each measure, scored on held-out trials
(``--test``, the demo's r6–r8 by default) and by leave-three-trials-out cross-validation over
all trials, beside the mean predictor; last, the frame preparation's time per frame with and
without the texture tracking (a ratio: the machine is shared). Run:
``python -m benchmarks.bench_freehand_texture --trials 18 --workers 2`` (``--remeasure`` after
a change of the measures: they are kept beside each session).
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks import smoke
from vbfe.acquire import SessionReader, record_session
from vbfe.demo import FREEHAND, FREEHAND_FIRST_SEED, DemoPlan, demo_config
from vbfe.estimate.displacement import DisplacementGrid
from vbfe.estimate.preparation import FramePreparer
from vbfe.estimate.sources import open_source
from vbfe.estimate.texture_motion import TextureMotion
from vbfe.recon import CloudReader, reconstruct_session
from vbfe.truth import session_bench, trial_duration_s, true_rig
from vbfe.truth.calibration import calibration_from_rig


def record(folder: Path, trials: list[int], plan: DemoPlan) -> None:
    """Record and reconstruct the textured freehand trials not yet in ``folder``."""
    config = demo_config(plan)
    yaml_text = calibration_from_rig(true_rig(config)).to_yaml_text()
    params, settings = config.sgbm, config.recon
    folder.mkdir(parents=True, exist_ok=True)
    for r in trials:
        path = folder / f"{FREEHAND}_r{r}.h5"
        if path.with_name(path.stem + ".clouds.h5").exists():
            continue
        bench = dict(
            protocol=FREEHAND,
            freehand_duration_s=plan.freehand_s,
            seed=FREEHAND_FIRST_SEED + r,
            textured=True,
        )
        trial = config.updated({"bench": bench})
        path.unlink(missing_ok=True)
        record_session(
            trial,
            path,
            duration_s=trial_duration_s(trial),
            operator="bench",
            notes=path.stem,
            calibration_yaml=yaml_text,
        )
        reconstruct_session(path, workers=1, sgbm_params=params, settings=settings)
        print(f"recorded {path.name}", flush=True)


def measure(path: Path, remeasure: bool = False) -> dict[str, np.ndarray]:
    """Per frame: force (N), depth-only and texture peak displacement, true visible
    displacement and its depth component (m); kept beside the session and reused unless
    ``remeasure``."""
    kept = path.with_suffix(".measures.npz")
    if kept.exists() and not remeasure:
        with np.load(kept) as stored:
            return dict(stored)
    source = open_source(path)
    force = np.linalg.norm(source.force_at_frames(), axis=1)
    source.close()
    with SessionReader(path) as reader:
        bench = session_bench(reader)
    with CloudReader(path.with_name(path.stem + ".clouds.h5")) as clouds:
        frames = clouds.frame_table("frame_index")
        rest_points, rest_colors = clouds.cloud(0)
        grid = DisplacementGrid(rest_points.astype(np.float64))
        motion, reason = TextureMotion.from_rest(rest_points, rest_colors)
        if motion is None:
            raise SystemExit(f"{path.name}: {reason}")
        depth, texture = [], []
        for i in range(clouds.n_frames):
            points, colors = clouds.cloud(i)
            depth.append(grid.peak_displacement_m(points.astype(np.float64)))
            texture.append(motion.peak_displacement_m(points, colors))
    u, _, _ = bench.trial.protocol.state(frames / bench.fps)
    visible = bench.trial.deformation_scale * u
    measures = {
        "force": force[frames],
        "depth": np.asarray(depth),
        "texture": np.asarray(texture),
        "visible": visible,
        "visible_z": visible * abs(bench.trial.sample.pull_direction[2]),
    }
    np.savez(kept, **measures)
    return measures


def feature_seconds(path: Path, frames: int = 40) -> tuple[float, float]:
    """Seconds per frame of the whole frame preparation (``FramePreparer.features``, demo's
    ``[train]`` settings) with and without the texture tracking, on one trial."""
    config = demo_config(DemoPlan.full()).train
    pool = config.pool_factor * config.n_points
    with CloudReader(path.with_name(path.stem + ".clouds.h5")) as clouds:
        loaded = [clouds.cloud(i) for i in range(min(frames, clouds.n_frames))]
    seconds = []
    for texture in (True, False):
        preparer = FramePreparer(loaded[0][0].astype(np.float64), config, loaded[0][1], texture)
        rng = np.random.default_rng(0)
        start = time.perf_counter()
        for points, colors in loaded:
            points = points.astype(np.float64)
            preparer.features(preparer.cropped(points), pool, rng, points, colors)
        seconds.append((time.perf_counter() - start) / len(loaded))
    return seconds[0], seconds[1]


def hooke_mae(
    trials: dict[int, dict[str, np.ndarray]], feature: str, train: list[int], test: list[int]
) -> float:
    """Held-out MAE (N) of F = k̂·d fitted on ``train`` (``mean``: the mean predictor)."""
    y = np.concatenate([trials[r]["force"] for r in train])
    y_test = np.concatenate([trials[r]["force"] for r in test])
    if feature == "mean":
        return float(np.abs(y.mean() - y_test).mean())
    d = np.nan_to_num(np.concatenate([trials[r][feature] for r in train]))
    d_test = np.nan_to_num(np.concatenate([trials[r][feature] for r in test]))
    return float(np.abs(d_test * (d @ y) / (d @ d) - y_test).mean())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=Path, default=Path("/tmp/vbfe-bench-texture"))
    parser.add_argument("--trials", type=int, default=18, help="freehand trials r0 … r(n-1)")
    parser.add_argument("--test", default="6,7,8", help="held-out trials (the demo's)")
    parser.add_argument(
        "--remeasure",
        action="store_true",
        help="measure again (after a change of the measures), not the kept ones",
    )
    parser.add_argument("--workers", type=int, default=1, help="trials measured at once")
    args = smoke.parse(parser, argv, trials=4, test="3")
    if args.smoke:
        args.sessions = smoke.scratch()
    numbers = list(range(args.trials))
    test = [int(r) for r in args.test.split(",")]
    record(args.sessions, numbers, DemoPlan.quick() if args.smoke else DemoPlan.full())
    paths = [args.sessions / f"{FREEHAND}_r{r}.h5" for r in numbers]
    with ProcessPoolExecutor(args.workers) as pool:
        trials = dict(
            zip(numbers, pool.map(measure, paths, [args.remeasure] * len(paths)), strict=False)
        )
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(
        "trial | texture gain vs 3D truth, residual sd (mm) | depth-only gain vs depth truth, "
        "residual sd (mm)"
    )
    for r, t in trials.items():
        cells = []
        for feature, truth in (("texture", "visible"), ("depth", "visible_z")):
            ok = np.isfinite(t[feature]) & (t[truth] > 5e-4)
            gain = float(t[feature][ok] @ t[truth][ok] / (t[truth][ok] @ t[truth][ok]))
            residual = (t[feature][ok] - gain * t[truth][ok]).std() * 1e3
            cells.append(f"{gain:.2f}, {residual:.2f}")
        print(f"r{r} | {cells[0]} | {cells[1]}")
    train = [r for r in numbers if r not in test]
    demo_train = [r for r in train if r < 6]  # the demo's freehand training trials
    folds = [numbers[i : i + 3] for i in range(0, len(numbers), 3)]
    print(
        f"Hooke's law held-out MAE (N) on trials {test}: trained on r0–r5 | trained on the "
        f"other {len(train)} trials | {len(folds)}-fold leave-3-trials-out CV mean"
    )
    for feature, label in (
        ("texture", "texture 3D displacement"),
        ("depth", "depth-only peak displacement"),
        ("visible", "true 3D displacement (ideal)"),
        ("mean", "mean predictor"),
    ):
        cv = np.mean(
            [hooke_mae(trials, feature, [r for r in numbers if r not in f], f) for f in folds]
        )
        print(
            f"{label} | {hooke_mae(trials, feature, demo_train, test):.3f} | "
            f"{hooke_mae(trials, feature, train, test):.3f} | {cv:.3f}"
        )
    with_texture, without = feature_seconds(paths[test[0]])
    print(
        f"frame preparation on r{test[0]}: {with_texture * 1e3:.0f} ms per frame with the "
        f"texture, {without * 1e3:.0f} ms without ({with_texture / without:.2f}x); load "
        f"average {os.getloadavg()[0]:.2f}"
    )


if __name__ == "__main__":
    main()
