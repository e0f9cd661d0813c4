"""Training the PointNet force regressor on recorded (or in-memory) sessions.

``train`` prepares the sessions, splits them by session, fits the baselines on the training
sessions, trains with NAdam on an MSE loss (force scaled by its training standard deviation),
stops early when the validation loss has not improved for ``patience`` epochs, and writes the
best network to a model file (see ``model_file.py``).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
import numpy as np
import torch

from vbfe.estimate.baselines import fit_baselines
from vbfe.estimate.dataset import (FrameBatches, PreparedSession, ProgressFn, SessionSplit,
                                   prepare_sessions, skipped_counts, split_by_session)
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.model_file import ForceModel, save_model
from vbfe.estimate.pointnet import PointNetRegressor
from vbfe.estimate.sources import SessionLike
from vbfe.estimate.train_config import TrainConfig


@dataclass
class TrainResult:
    """What a training run produced and how it went."""

    model_path: Path
    split: SessionSplit
    epochs_run: int
    best_epoch: int
    best_val_loss: float  # MSE of force / training force std (dimensionless)
    val_mae_n: float  # PointNet MAE on the validation sessions (training sessions if none)
    baseline_val_mae_n: dict[str, float]
    history: list[dict[str, float]]
    skipped: dict[str, dict[str, int]]
    duration_s: float


def _build_network(config: TrainConfig, train_batches: FrameBatches) -> PointNetRegressor:
    network = PointNetRegressor(config.n_outputs, config.conv_channels, config.head_channels,
                                config.dropout, config.global_features)
    targets = torch.from_numpy(train_batches.targets)
    with torch.no_grad():
        features = torch.cat([network.cloud_features(points)
                              for points, _ in train_batches.batches(256, rng=None)])
    network.set_normalization(targets.mean(0), targets.std(0, unbiased=False),
                              features.mean(0), features.std(0, unbiased=False))
    return network


def _mean_loss(network: PointNetRegressor, batches: FrameBatches, batch_size: int
               ) -> tuple[float, float]:
    """(scaled MSE, MAE of the error vector in newtons) over all frames, no augmentation."""
    network.eval()
    squared, absolute, n = 0.0, 0.0, 0
    with torch.no_grad():
        for points, y in batches.batches(batch_size, rng=None):
            error = network(points) - y
            squared += float(((error / network.target_std) ** 2).mean(1).sum())
            absolute += float(error.norm(dim=1).sum())
            n += len(y)
    return squared / n, absolute / n


def _session_mae(baseline_predict: Callable[[np.ndarray], np.ndarray],
                 sessions: Sequence[PreparedSession]) -> float:
    errors = [np.linalg.norm(baseline_predict(s.displacement_m) - s.targets_n, axis=1)
              for s in sessions]
    return float(np.concatenate(errors).mean())


def train(sessions: Sequence[SessionLike], out: str | Path, config: TrainConfig | None = None,
          progress: ProgressFn | None = None) -> TrainResult:
    """Train a force regressor on sessions (paths with clouds sidecars, or ``SessionClouds``).

    ``progress(stage, done, total)`` is called per prepared session (stage ``"sessions"``) and
    per epoch (``"epochs"``). Returns a ``TrainResult``; the model is written to ``out``.
    """
    config = config or TrainConfig()
    started = time.monotonic()
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)

    prepared = prepare_sessions(sessions, config, progress)
    by_name = {s.name: s for s in prepared}
    if len(by_name) != len(prepared):
        raise EstimateError("the same session was given twice; give each session once")
    split = split_by_session(prepared, config.val_fraction, config.test_fraction, config.seed)
    train_sets = [by_name[n] for n in split.train]
    check_sets = [by_name[n] for n in split.val] or train_sets
    baselines = fit_baselines(train_sets)

    train_batches = FrameBatches(train_sets, config.n_points)
    check_batches = FrameBatches(check_sets, config.n_points)
    network = _build_network(config, train_batches)
    optimizer = torch.optim.NAdam(network.parameters(), lr=config.learning_rate)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=config.epochs)

    history: list[dict[str, float]] = []
    best_loss, best_epoch, best_state = float("inf"), 0, copy.deepcopy(network.state_dict())
    for epoch in range(1, config.epochs + 1):
        network.train()
        total, count = 0.0, 0
        for points, y in train_batches.batches(config.batch_size, rng):
            if len(y) < 2:  # batch norm needs two samples
                continue
            loss = (((network(points) - y) / network.target_std) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += loss.item() * len(y)
            count += len(y)
        schedule.step()
        check_loss, check_mae = _mean_loss(network, check_batches, 4 * config.batch_size)
        history.append({"epoch": epoch, "train_loss": total / max(count, 1),
                        "val_loss": check_loss, "val_mae_n": check_mae})
        if check_loss < best_loss:
            best_loss, best_epoch = check_loss, epoch
            best_state = copy.deepcopy(network.state_dict())
        if progress is not None:
            progress("epochs", epoch, config.epochs)
        out_of_time = config.time_limit_s > 0 and time.monotonic() - started > config.time_limit_s
        if epoch - best_epoch >= config.patience or out_of_time:
            break
    network.load_state_dict(best_state)
    network.eval()

    skipped = skipped_counts(prepared)
    record = {
        "split": split.to_dict(),
        "early_stopping_on": "val" if split.val else "train",
        "normalization": {"target_mean_n": network.target_mean.tolist(),
                          "target_std_n": network.target_std.tolist(),
                          "feature_mean": network.feature_mean.tolist(),
                          "feature_std": network.feature_std.tolist()},
        "history": history, "best_epoch": best_epoch, "skipped": skipped,
        "conditions": {s.name: s.conditions for s in prepared},
    }
    path = save_model(out, ForceModel(network, config, baselines, record))
    return TrainResult(
        model_path=path, split=split, epochs_run=len(history), best_epoch=best_epoch,
        best_val_loss=best_loss, val_mae_n=history[best_epoch - 1]["val_mae_n"],
        baseline_val_mae_n={name: _session_mae(b.predict, check_sets)
                            for name, b in baselines.items()},
        history=history, skipped=skipped, duration_s=time.monotonic() - started)
