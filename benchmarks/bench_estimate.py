"""Force-estimation benchmark: train, evaluate against the baselines, time inference.

    python -m benchmarks.bench_estimate                      # synthetic 3 stiffness × 3 speeds
    python -m benchmarks.bench_estimate run*.h5 --out DIR    # recorded sessions with clouds
    python -m benchmarks.bench_estimate --sim-bench 3 --out DIR   # record + reconstruct first

Held-out sessions (one repeat per condition) are evaluated. Per method (every candidate and
baseline) it prints the training time, the validation and held-out MAE (also as a ratio to the
mean predictor's) and the inference latency of one 2048-point cloud through the live path
(``FramePredictor``: ROI, features against the rest cloud, the method; batch 1, CPU); then the
paper-size networks' latency and training throughput (clouds/s through forward + backward +
step) on the CPU and, when torch sees one, on CUDA. Times are also given as ratios to a
reference matmul of the paper network's widest layer (2048×128 @ 128×1024), timed in the same
run, because the machine may be shared.

    python -m benchmarks.bench_estimate --timing-only        # latency and throughput only
"""

from __future__ import annotations

import argparse
import os
import tempfile
import timeit
from functools import partial
from pathlib import Path

import numpy as np
import torch

from benchmarks import smoke
from vbfe.estimate.evaluation import evaluate
from vbfe.estimate.inference import FramePredictor
from vbfe.estimate.model_file import ForceModel, load_model
from vbfe.estimate.pointnet import PointNetRegressor, TemporalPointNet
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


def reference_time_s(n_points: int = 2048) -> float:
    """The reference: one matmul of the paper network's widest layer, timed now."""
    rng = np.random.default_rng(0)
    a = torch.from_numpy(rng.normal(size=(n_points, 128)).astype(np.float32))
    b = torch.from_numpy(rng.normal(size=(128, 1024)).astype(np.float32))
    reference = best_time_s(lambda: a @ b)
    print(f"reference matmul {n_points}x128 @ 128x1024: {reference * 1e3:.2f} ms")
    return reference


def _patch(n_points: int, rng: np.random.Generator) -> np.ndarray:
    patch = synthetic_sessions(repeats=1, points_per_side=64)[0].clouds[-1]
    patch = patch[np.isfinite(patch).all(axis=1)]
    return patch[rng.choice(len(patch), n_points, replace=False)].astype(np.float32)


def networks(conv: list[int], head: list[int], k: int) -> dict[str, torch.nn.Module]:
    """PointNet and the temporal model (window of k) of one width."""
    return {
        "PointNet": PointNetRegressor(1, conv, head),
        f"temporal k={k}": TemporalPointNet(1, k, conv, head),
    }


def inference_timing(reference: float, k: int, n_points: int = 2048) -> None:
    """Latency of one cloud (batch 1) through the paper-size PointNet and temporal model, CPU."""
    rng = np.random.default_rng(0)
    cloud = torch.from_numpy(_patch(n_points, rng))[None]
    window = cloud[:, None].expand(1, k + 1, n_points, 3).contiguous()
    for name, net in networks([64, 128, 1024], [512, 256], k).items():
        net.eval()
        x = window if isinstance(net, TemporalPointNet) else cloud
        with torch.no_grad():
            t = best_time_s(partial(net, x))
        print(
            f"inference, one {n_points}-point cloud, batch 1, CPU, paper size 64-128-1024, "
            f"{name}: {t * 1e3:.2f} ms = {t / reference:.1f}x reference"
        )


def method_latency_s(model: ForceModel, method: str, rest: np.ndarray, cloud: np.ndarray) -> float:
    """Seconds for one raw cloud through the live path with ``method`` as the shipped model."""
    predictor = FramePredictor(ForceModel(model.config, model.estimators, method, model.record))
    predictor.predict(rest)
    return best_time_s(lambda: predictor.predict(cloud))


def method_table(
    reference: float,
    model: ForceModel,
    fit_seconds: dict[str, float],
    held_out: dict[str, float],
    n_points: int = 2048,
) -> None:
    """Per method: training time, validation and held-out MAE, live-path latency."""
    rng = np.random.default_rng(0)
    session = synthetic_sessions(repeats=1, points_per_side=64)[0]
    rest, pressed = (c[np.isfinite(c).all(axis=1)] for c in (session.clouds[0], session.clouds[-1]))
    rest, pressed = (c[rng.choice(len(c), n_points, replace=False)] for c in (rest, pressed))
    validation = model.record["validation_mae_n"]
    print(
        f"{'method':>26} {'train s':>8} {'val MAE':>8} {'test MAE':>9} {'x mean':>7} "
        f"{'latency ms':>11} {'x ref':>6}   (selected: {model.selected})"
    )
    for method in model.estimators:
        t = method_latency_s(model, method, rest, pressed)
        fit = fit_seconds.get(method, fit_seconds.get("baselines", float("nan")))
        print(
            f"{method:>26} {fit:8.2f} {validation[method]:8.3f} {held_out[method]:9.3f} "
            f"{held_out[method] / held_out['mean']:7.2f} {t * 1e3:11.2f} "
            f"{t / reference:6.1f}"
        )
    print(
        "(train s of mean, linear_displacement, hooke, mlp_displacement_history: all four "
        "baselines together)"
    )


def _train_step(
    net: torch.nn.Module,
    x: torch.Tensor,
    y: torch.Tensor,
    optimizer: torch.optim.Optimizer,
    device: str,
) -> None:
    loss = ((net(x) - y) ** 2).mean()
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    if device == "cuda":
        torch.cuda.synchronize()


def training_throughput(
    reference: float,
    conv: list[int],
    head: list[int],
    k: int,
    n_points: int,
    batch: int = 32,
    steps: int = 5,
) -> None:
    """Clouds per second through forward + backward + optimizer step, CPU and CUDA."""
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    rng = np.random.default_rng(1)
    clouds = torch.from_numpy(np.stack([_patch(n_points, rng) for _ in range(batch)]))
    for device in devices:
        for name, net in networks(conv, head, k).items():
            net.to(device).train()
            x = (
                clouds[:, None].expand(batch, k + 1, n_points, 3).contiguous()
                if isinstance(net, TemporalPointNet)
                else clouds
            ).to(device)
            y = torch.ones(batch, 1, device=device)
            optimizer = torch.optim.NAdam(net.parameters(), lr=1e-3)
            step = partial(_train_step, net, x, y, optimizer, device)
            t = best_time_s(step, repeats=steps)
            per_cloud = t / (batch * (k + 1 if isinstance(net, TemporalPointNet) else 1))
            print(
                f"training, {device}, {name} {conv}, {n_points} points, batch {batch}: "
                f"{batch / t:.0f} examples/s ({1 / per_cloud:.0f} clouds/s), "
                f"step {t * 1e3:.0f} ms = {t / reference:.0f}x reference"
            )


def record_sim_bench(out: Path, repeats: int, fps: float, width: int, height: int) -> list[Path]:
    """Record and reconstruct simulated-bench sessions for every stiffness × speed condition."""
    from vbfe.acquire import record_session
    from vbfe.drivers.sim import SimBench
    from vbfe.recon import reconstruct_session
    from vbfe.rig_config import builtin_rig
    from vbfe.truth import calibration_from_rig

    paths = []
    for k in STIFFNESSES_N_PER_M:
        for v in SPEEDS_M_PER_S:
            for r in range(repeats):
                trial = dict(
                    width=width,
                    height=height,
                    fps=fps,
                    seed=r,
                    stiffness_n_per_m=k,
                    pull_speed_m_per_s=v,
                )
                config = builtin_rig({"bench": trial})
                bench = SimBench.from_config(config.tables["bench"])
                duration_s = 3.0 / (k * v) + bench.describe()["hold_s"] + 1.0
                path = out / f"sim_k{k:g}_v{v:g}_r{r}.h5"
                if not path.with_name(path.stem + ".clouds.h5").exists():
                    record_session(
                        config,
                        path,
                        duration_s=duration_s,
                        calibration_yaml=calibration_from_rig(bench.rig).to_yaml_text(),
                    )
                    reconstruct_session(path)
                paths.append(path)
                print(f"  {path.name}: recorded and reconstructed", flush=True)
    return paths


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="*", help="sessions with clouds (default: synthetic)")
    parser.add_argument("--out", default=None, help="directory for model and report")
    parser.add_argument("--repeats", type=int, default=4, help="synthetic repeats per condition")
    parser.add_argument("--fps", type=float, default=5.0, help="synthetic/simulated frame rate")
    parser.add_argument(
        "--sim-bench",
        type=int,
        default=0,
        metavar="REPEATS",
        help="record this many simulated-bench sessions per condition",
    )
    parser.add_argument(
        "--size",
        type=int,
        nargs=2,
        default=(320, 180),
        metavar=("W", "H"),
        help="simulated-bench image size",
    )
    parser.add_argument("--epochs", type=int, default=60)
    parser.add_argument("--points", type=int, default=256)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--time-limit", type=float, default=540.0, help="training seconds")
    parser.add_argument("--temporal-frames", type=int, default=3, help="temporal model's k")
    parser.add_argument(
        "--timing-only", action="store_true", help="only inference latency and training throughput"
    )
    args = smoke.parse(parser, argv, repeats=1, epochs=2, time_limit=10.0, points=64)
    torch.set_num_threads(args.threads)
    conv, head = [32, 64, 256], [128, 64]
    print(f"load average (1, 5, 15 min) at start: {os.getloadavg()} on {os.cpu_count()} CPUs")
    reference = reference_time_s()
    if args.timing_only:
        inference_timing(reference, args.temporal_frames)
        training_throughput(reference, conv, head, args.temporal_frames, args.points)
        return

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
    config = TrainConfig(
        epochs=args.epochs,
        n_points=args.points,
        batch_size=32,
        learning_rate=3e-3,
        patience=15,
        conv_channels=conv,
        head_channels=head,
        dropout=0.1,
        val_fraction=test_fraction / 2,
        test_fraction=test_fraction,
        time_limit_s=args.time_limit,
        threads=args.threads,
        temporal_frames=args.temporal_frames,
        temporal_span_frames=2 * args.temporal_frames,
        # the smoke run: every candidate still trained and evaluated, each as briefly as it can
        **(
            dict(cnn_epochs=args.epochs, interval_folds=False, select_min_val_frames=0)
            if args.smoke
            else {}
        ),
    )
    print(
        f"{n_total} sessions; training {config.conv_channels} / {config.head_channels}, "
        f"{config.n_points} points, {config.threads} threads"
    )
    result = train(sessions, out / "model.pt", config)
    print(
        f"training: {result.duration_s:.0f} s, PointNet {result.epochs_run} epochs (best "
        f"{result.best_epoch}); split {len(result.split.train)}/{len(result.split.val)}/"
        f"{len(result.split.test)} sessions train/val/test"
    )
    by_name = {s.name if isinstance(s, SessionClouds) else str(s): s for s in sessions}
    held_out = [by_name[name] for name in result.split.test]
    report = evaluate(result.model_path, held_out, out / "report")
    method_table(
        reference,
        load_model(result.model_path),
        result.fit_seconds,
        {m: report.mae_n(m) for m in report.metrics},
    )
    inference_timing(reference, args.temporal_frames)
    training_throughput(reference, conv, head, args.temporal_frames, args.points)
    print(f"load average at end: {os.getloadavg()}")
    print(f"report: {out / 'report' / 'report.md'}")


if __name__ == "__main__":
    main()
