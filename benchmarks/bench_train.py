"""What training costs, stage by stage, and how far each network is from a bare PyTorch loop.

    python -m benchmarks.bench_train CLOUDS.h5 --train 0:90 --val 95:115 --test 120:150
    python -m benchmarks.bench_train run*.h5                 # recorded sessions (e.g. a demo's)
    python -m benchmarks.bench_train --demo-like             # synthetic sessions, quick demo's plan

Per stage of ``vbfe train`` (preparation, every candidate, the selection and interval folds)
and of the evaluation that follows it: wall and CPU seconds (CPU over wall near the number of
cores busy: on a shared machine wall time says as much about the others as about vbfe). Then,
per network, its median epoch's wall time in training, and the CPU seconds of an epoch of
the training loop (``fit_network``: fresh point draws, schedule, validation pass) against an
epoch of a bare PyTorch loop of the same network on the same prepared tensors (points drawn
beforehand, no validation, no schedule), measured back to back: the ratio is what the training
loop adds, in CPU time so that the others' load does not move it. The load average is
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

from benchmarks import smoke
from vbfe.demo import DemoPlan
from vbfe.estimate.dataset import FrameBatches, prepare_sessions
from vbfe.estimate.evaluation import evaluate
from vbfe.estimate.network_training import build_network, fit_network
from vbfe.estimate.splits import parse_range
from vbfe.estimate.stage_times import cpu_seconds
from vbfe.estimate.synthetic import synthetic_sessions
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.training import make_split, train, use_threads
from vbfe.rig_config import load_rig


def load() -> str:
    return "load average " + ", ".join(f"{v:.1f}" for v in os.getloadavg())


def _batches(
    config: TrainConfig, prepared: list, window: tuple[int, ...]
) -> tuple[FrameBatches, FrameBatches | None]:
    split = make_split(prepared, config)
    train, val = split.frames("train", prepared), split.frames("val", prepared)
    check = FrameBatches(val, config.n_points, window, config.val_max_frames) if val else None
    return FrameBatches(train, config.n_points, window), check


def bare_epoch_s(config: TrainConfig, prepared: list, window: tuple[int, ...]) -> list[float]:
    """CPU seconds of each of three epochs of a bare loop: the network, its batches drawn
    beforehand, no validation, no schedule."""
    batches, _ = _batches(config, prepared, window)
    torch.manual_seed(config.seed)
    network = build_network(config, batches, temporal=bool(window))
    rng = np.random.default_rng(config.seed)
    drawn = [(x, y) for x, y in batches.batches(config.batch_size, rng) if len(y) >= 2]
    optimizer = torch.optim.NAdam(network.parameters(), lr=config.learning_rate)
    network.train()
    times = []
    for _ in range(3):
        clock = time.process_time()
        for x, y in drawn:
            loss = (((network(x) - y) / network.target_std) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        times.append(time.process_time() - clock)
    return times


def loop_epoch_s(config: TrainConfig, prepared: list, window: tuple[int, ...]) -> list[float]:
    """CPU seconds of each of three epochs of the training loop (``fit_network``: fresh draws,
    schedule, the validation pass) on the same tensors."""
    batches, check = _batches(config, prepared, window)
    torch.manual_seed(config.seed)
    network = build_network(config, batches, temporal=bool(window))
    marks = [time.process_time()]
    fit_network(
        network,
        batches,
        check,
        config,
        3,
        torch.device("cpu"),
        np.random.default_rng(config.seed),
        None,
        lambda done, total, best: marks.append(time.process_time()),
    )
    return list(np.diff(marks))


def epoch_ratio(config: TrainConfig, prepared: list, window: tuple[int, ...]) -> str:
    """The training loop's epoch against the bare loop's, in CPU seconds (what the process
    spent, whatever the load), each the fastest of three epochs, measured back to back."""
    use_threads(config.threads)
    bare = min(bare_epoch_s(config, prepared, window))
    loop = min(loop_epoch_s(config, prepared, window))
    return f"epoch CPU: training loop {loop:.3f} s, bare loop {bare:.3f} s: {loop / bare:.2f}x"


def bench(sessions: list, config: TrainConfig, label: str) -> None:
    print(f"== {label}: {len(sessions)} session(s); {load()}")
    use_threads(config.threads)
    with tempfile.TemporaryDirectory() as tmp:
        wall, cpu = time.perf_counter(), cpu_seconds()
        result = train(sessions, Path(tmp) / "model.pt", config)
        total_wall, total_cpu = time.perf_counter() - wall, cpu_seconds() - cpu
        wall, cpu = time.perf_counter(), cpu_seconds()
        evaluate(result.model_path, sessions, Path(tmp) / "evaluation")  # its held-out frames
        histories = load_histories(result)  # before the temporary folder goes
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
    windows = {"pointnet": (), "temporal": tuple(config.temporal_window)}
    prepared = prepare_sessions(sessions, config, texture=False)
    for name, h in histories.items():
        if name not in windows or not h.get("epoch_seconds"):
            continue
        epoch = statistics.median(h["epoch_seconds"])
        print(
            f"{name}: median epoch {epoch:.3f} s wall in training ({len(h['epoch_seconds'])} "
            f"epochs, best {h['best_epoch']}, {h['stopped_by']}); "
            f"{epoch_ratio(config, prepared, windows[name])}; {load()}"
        )


def load_histories(result: Any) -> dict[str, Any]:
    from vbfe.estimate.model_file import load_model

    return load_model(result.model_path).record["histories"]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="*", help="sessions with clouds, or clouds files")
    parser.add_argument("--demo-like", action="store_true", help="synthetic, the quick demo's plan")
    parser.add_argument("--config", help="rig config whose [train] table to use")
    parser.add_argument("--epochs", type=int, help="every network's epochs (default: the plan's)")
    for part in ("train", "val", "test"):
        parser.add_argument(f"--{part}", metavar="START:STOP", help=f"{part} frames (time split)")
    args = smoke.parse(parser, argv, demo_like=True, sessions=[], epochs=1)
    table = load_rig(args.config).tables["train"] if args.config else {}
    overrides: dict[str, Any] = {}
    if args.epochs:
        overrides.update(epochs=args.epochs, temporal_epochs=args.epochs, cnn_epochs=args.epochs)
    for part in ("train", "val", "test"):
        text = getattr(args, part)
        if text:
            overrides[f"{part}_frames"] = parse_range(text, f"--{part}")
            overrides["split"] = "time"
    if args.sessions:
        config = TrainConfig.from_table(table, **overrides)
        bench(args.sessions, config, "recorded")
    if args.demo_like or not args.sessions:
        sessions = synthetic_sessions(repeats=2, seed=1, prefix="demo", fps=10)
        plan = {**DemoPlan.quick().train_options(), **table}
        bench(sessions, TrainConfig.from_table(plan, **overrides), "demo-like")


if __name__ == "__main__":
    main()
