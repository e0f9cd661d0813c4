"""What training costs, stage by stage, and how far each network is from a bare PyTorch loop.

    python benchmarks/bench_train.py CLOUDS.h5 --train 0:90 --val 95:115 --test 120:150
    python benchmarks/bench_train.py run*.h5                 # recorded sessions (e.g. a demo's)
    python benchmarks/bench_train.py --demo-like             # synthetic sessions, quick demo's plan

Per stage of ``vbfe train`` (preparation, every candidate, the selection and interval folds)
and of the evaluation that follows it: wall and CPU seconds (CPU over wall near the number of
cores busy: on a shared machine wall time says as much about the others as about vbfe). Then,
per network, its median epoch in training (validation pass included) against one epoch of a
bare PyTorch loop of the same network on the same prepared tensors (points drawn beforehand,
no validation, no schedule): the ratio is what the training loop adds. The load average is
printed beside the figures. ``--config`` reads a rig config's ``[train]`` table; without one
the defaults (the paper's network) are used, or, with ``--demo-like``, the quick demo's plan.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vbfe.demo import DemoPlan
from vbfe.estimate.dataset import FrameBatches, prepare_sessions
from vbfe.estimate.evaluation import evaluate
from vbfe.estimate.network_training import build_network
from vbfe.estimate.splits import parse_range
from vbfe.estimate.stage_times import cpu_seconds
from vbfe.estimate.synthetic import synthetic_sessions
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.training import make_split, train, use_threads
from vbfe.rig_config import load_rig


def load() -> str:
    return "load average " + ", ".join(f"{v:.1f}" for v in os.getloadavg())


def bare_epoch_s(config: TrainConfig, prepared: list, window: tuple[int, ...]) -> float:
    """Seconds of one epoch of a bare loop: the network, its batches drawn beforehand."""
    parts = make_split(prepared, config).frames("train", prepared)
    batches = FrameBatches(parts, config.n_points, window)
    torch.manual_seed(config.seed)
    network = build_network(config, batches, temporal=bool(window))
    rng = np.random.default_rng(config.seed)
    drawn = [(x, y) for x, y in batches.batches(config.batch_size, rng) if len(y) >= 2]
    optimizer = torch.optim.NAdam(network.parameters(), lr=config.learning_rate)
    network.train()
    times = []
    for _ in range(3):  # the fastest of three epochs
        clock = time.perf_counter()
        for x, y in drawn:
            loss = (((network(x) - y) / network.target_std) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        times.append(time.perf_counter() - clock)
    return min(times)


def bench(sessions: list, config: TrainConfig, label: str) -> None:
    print(f"== {label}: {len(sessions)} session(s); {load()}")
    use_threads(config.threads)
    with tempfile.TemporaryDirectory() as tmp:
        wall, cpu = time.perf_counter(), cpu_seconds()
        result = train(sessions, Path(tmp) / "model.pt", config)
        total_wall, total_cpu = time.perf_counter() - wall, cpu_seconds() - cpu
        wall, cpu = time.perf_counter(), cpu_seconds()
        evaluate(result.model_path, sessions, Path(tmp) / "evaluation")  # its held-out frames
        stages = dict(result.stage_seconds)
        stages["evaluation"] = {
            "wall_s": time.perf_counter() - wall,
            "cpu_s": cpu_seconds() - cpu,
        }
    print(f"{'stage':>42} {'wall s':>8} {'CPU s':>8} {'CPU/wall':>8}")
    for stage, s in stages.items():
        ratio = s["cpu_s"] / s["wall_s"] if s["wall_s"] > 0 else float("nan")
        print(f"{stage:>42} {s['wall_s']:8.2f} {s['cpu_s']:8.2f} {ratio:8.2f}")
    print(f"{'train (all)':>42} {total_wall:8.2f} {total_cpu:8.2f} {total_cpu / total_wall:8.2f}")
    print(
        f"selected {result.selected}; validation MAE (N): "
        + ", ".join(f"{m} {v:.3f}" for m, v in result.val_mae_n.items())
    )
    for note in result.notes:
        print("  note:", note)
    histories = load_histories(result)
    windows = {"pointnet": (), "temporal": tuple(config.temporal_window)}
    prepared = prepare_sessions(sessions, config, texture=False)
    for name, h in histories.items():
        if name not in windows or not h.get("epoch_seconds"):
            continue
        epoch = statistics.median(h["epoch_seconds"])
        bare = bare_epoch_s(config, prepared, windows[name])
        print(
            f"{name}: epoch {epoch:.3f} s in training ({len(h['epoch_seconds'])} epochs, best "
            f"{h['best_epoch']}, {h['stopped_by']}), bare loop {bare:.3f} s: "
            f"{epoch / bare:.2f}x; {load()}"
        )


def load_histories(result: Any) -> dict[str, Any]:
    from vbfe.estimate.model_file import load_model

    return load_model(result.model_path).record["histories"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="*", help="sessions with clouds, or clouds files")
    parser.add_argument("--demo-like", action="store_true", help="synthetic, the quick demo's plan")
    parser.add_argument("--config", help="rig config whose [train] table to use")
    for part in ("train", "val", "test"):
        parser.add_argument(f"--{part}", metavar="START:STOP", help=f"{part} frames (time split)")
    args = parser.parse_args()
    table = load_rig(args.config).tables["train"] if args.config else {}
    overrides: dict[str, Any] = {}
    for part in ("train", "val", "test"):
        text = getattr(args, part)
        if text:
            overrides[f"{part}_frames"] = parse_range(text, f"--{part}")
            overrides["split"] = "time"
    if args.sessions:
        bench(args.sessions, TrainConfig.from_table(table, **overrides), "recorded")
    if args.demo_like or not args.sessions:
        sessions = synthetic_sessions(repeats=2, seed=1, prefix="demo", fps=10)
        bench(
            sessions,
            TrainConfig.from_table({**DemoPlan.quick().train_options(), **table}),
            "demo-like",
        )


if __name__ == "__main__":
    main()
