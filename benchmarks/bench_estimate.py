"""Force-estimation benchmark: train, evaluate against the baselines, time inference.

    python benchmarks/bench_estimate.py                      # synthetic 3 stiffness × 3 speeds
    python benchmarks/bench_estimate.py run*.h5 --out DIR    # recorded sessions with clouds
    python benchmarks/bench_estimate.py --sim-bench 3 --out DIR   # record + reconstruct first

Held-out sessions (one repeat per condition) are evaluated; prints PointNet's MAE as a ratio to
the mean predictor's, and the inference time of one 2048-point cloud as a ratio to a reference
matmul of the network's widest layer (2048×128 @ 128×1024), timed in the same run.
"""

from __future__ import annotations

import argparse
import tempfile
import timeit
from pathlib import Path

import numpy as np
import torch

from vbfe.estimate.evaluation import evaluate
from vbfe.estimate.model_file import ForceModel, load_model
from vbfe.estimate.pointnet import PointNetRegressor
from vbfe.estimate.sources import SessionClouds
from vbfe.estimate.synthetic import synthetic_sessions
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.training import train

STIFFNESSES_N_PER_M = (40.0, 80.0, 200.0)
SPEEDS_M_PER_S = (0.01, 0.005, 0.002)


def best_time_s(fn, repeats: int = 20) -> float:
    """Fastest of ``repeats`` single calls (after one warm-up)."""
    fn()
    return min(timeit.repeat(fn, number=1, repeat=repeats))


def inference_timing(model: ForceModel, n_points: int = 2048) -> None:
    """Print the time of one cloud through the trained and the paper-sized network."""
    rng = np.random.default_rng(0)
    patch = synthetic_sessions(repeats=1, points_per_side=64)[0].clouds[-1]
    patch = patch[np.isfinite(patch).all(axis=1)]
    cloud = patch[rng.choice(len(patch), n_points, replace=False)][None].astype(np.float32)
    a = torch.from_numpy(rng.normal(size=(n_points, 128)).astype(np.float32))
    b = torch.from_numpy(rng.normal(size=(128, 1024)).astype(np.float32))
    reference = best_time_s(lambda: a @ b)
    paper = ForceModel(PointNetRegressor().eval(), model.config, model.baselines)
    print(f"reference matmul {n_points}x128 @ 128x1024: {reference * 1e3:.2f} ms")
    for label, m in (("trained model", model), ("paper-size model 3-64-128-1024", paper)):
        t = best_time_s(lambda: m.predict_points(cloud))
        print(f"inference, one {n_points}-point cloud, {label}: {t * 1e3:.2f} ms "
              f"= {t / reference:.1f}x reference (goal <= 20 ms)")


def record_sim_bench(out: Path, repeats: int, fps: float, width: int, height: int) -> list[Path]:
    """Record and reconstruct simulated-bench sessions for every stiffness × speed condition."""
    from vbfe.acquire import record_session
    from vbfe.config import default_config
    from vbfe.drivers.sim import SimBench
    from vbfe.recon import reconstruct_session
    from vbfe.truth import calibration_from_rig

    paths = []
    for k in STIFFNESSES_N_PER_M:
        for v in SPEEDS_M_PER_S:
            for r in range(repeats):
                config = default_config()
                config["bench"].update(width=width, height=height, fps=fps, seed=r,
                                       stiffness_n_per_m=k, pull_speed_m_per_s=v)
                bench = SimBench.from_config(config["bench"])
                duration_s = 3.0 / (k * v) + bench.describe()["hold_s"] + 1.0
                path = out / f"sim_k{k:g}_v{v:g}_r{r}.h5"
                if not path.with_name(path.stem + ".clouds.h5").exists():
                    record_session(config, path, duration_s=duration_s,
                                   calibration_yaml=calibration_from_rig(bench.rig).to_yaml_text())
                    reconstruct_session(path)
                paths.append(path)
                print(f"  {path.name}: recorded and reconstructed", flush=True)
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="*", help="sessions with clouds (default: synthetic)")
    parser.add_argument("--out", default=None, help="directory for model and report")
    parser.add_argument("--repeats", type=int, default=4, help="synthetic repeats per condition")
    parser.add_argument("--fps", type=float, default=5.0, help="synthetic/simulated frame rate")
    parser.add_argument("--sim-bench", type=int, default=0, metavar="REPEATS",
                        help="record this many simulated-bench sessions per condition")
    parser.add_argument("--size", type=int, nargs=2, default=(320, 180), metavar=("W", "H"),
                        help="simulated-bench image size")
    parser.add_argument("--epochs", type=int, default=60)
    parser.add_argument("--points", type=int, default=256)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--time-limit", type=float, default=540.0, help="training seconds")
    args = parser.parse_args()

    out = Path(args.out or tempfile.mkdtemp(prefix="bench_estimate_"))
    if args.sessions:
        sessions = list(args.sessions)
    elif args.sim_bench:
        sessions = record_sim_bench(out, args.sim_bench, args.fps, *args.size)
    else:
        conditions = [(k, v) for k in STIFFNESSES_N_PER_M for v in SPEEDS_M_PER_S]
        sessions = synthetic_sessions(conditions, repeats=args.repeats, seed=0, fps=args.fps)
    n_total = len(sessions)
    test_fraction = 1 / max(3, args.sim_bench or args.repeats)  # ~ one repeat per condition
    config = TrainConfig(epochs=args.epochs, n_points=args.points, batch_size=32,
                         learning_rate=3e-3, patience=15, conv_channels=[32, 64, 256],
                         head_channels=[128, 64], dropout=0.1, val_fraction=test_fraction / 2,
                         test_fraction=test_fraction, time_limit_s=args.time_limit,
                         threads=args.threads)
    print(f"{n_total} sessions; training {config.conv_channels} / {config.head_channels}, "
          f"{config.n_points} points, {config.threads} threads")
    result = train(sessions, out / "model.pt", config)
    print(f"training: {result.duration_s:.0f} s, {result.epochs_run} epochs (best "
          f"{result.best_epoch}); split {len(result.split.train)}/{len(result.split.val)}/"
          f"{len(result.split.test)} sessions train/val/test")
    by_name = {s.name if isinstance(s, SessionClouds) else str(s): s for s in sessions}
    held_out = [by_name[name] for name in result.split.test]
    report = evaluate(result.model_path, held_out, out / "report")
    mean_mae = report.mae_n("mean")
    for method in report.metrics:
        mae = report.mae_n(method)
        print(f"held-out {method:>20}: MAE {mae:.3f} N = {mae / mean_mae:.2f}x mean predictor")
    inference_timing(load_model(result.model_path))
    print(f"report: {out / 'report' / 'report.md'}")


if __name__ == "__main__":
    main()
