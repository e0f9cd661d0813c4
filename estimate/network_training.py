"""Training the PointNet force regressor and the temporal model (the network candidates).

``fit_network`` trains with NAdam on an MSE loss (force scaled by its training standard
deviation) under a per-step cosine learning rate over the configured epochs, and keeps the
network of the epoch with the lowest validation loss (measured on a fixed validation subsample
with fixed point draws); without validation frames it keeps the last epoch. Nothing depends on
the wall clock: the time limit is a guard that stops training, and the caller says so.
The temporal model starts as the trained PointNet with its motion correction at zero, and its
starting weights compete in the best-epoch choice, so on the validation frames it is never
worse than PointNet.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from vbfe.common.errors import EstimateError
from vbfe.estimate.dataset import FrameBatches
from vbfe.estimate.pointnet import PointNetRegressor, TemporalPointNet
from vbfe.estimate.train_config import TrainConfig


@dataclass
class FitOutcome:
    """How one network's training went."""

    history: list[dict[str, float]]
    best_epoch: int
    best_val_loss: float
    val_mae_n: float
    stopped_by: str  # "epochs", "patience", "time limit" or "refit" (``stop_after``)
    start_val_loss: float = float("nan")  # of the starting weights (warm start only)
    epoch_seconds: list[float] = field(default_factory=list)  # wall time of each epoch


def resolve_device(name: str) -> torch.device:
    """``auto`` → CUDA when torch sees a GPU, else CPU; ``cuda`` without a GPU is an error."""
    if name == "cuda" and not torch.cuda.is_available():
        raise EstimateError(
            "--device cuda: torch sees no CUDA device here; use --device cpu or auto"
        )
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    return torch.device(name)


def build_network(
    config: TrainConfig, train_batches: FrameBatches, temporal: bool
) -> PointNetRegressor:
    hparams: dict[str, Any] = dict(
        n_outputs=config.n_outputs,
        conv_channels=config.conv_channels,
        head_channels=config.head_channels,
        dropout=config.dropout,
        global_features=config.global_features,
        rest_depth=config.rest_depth,
    )
    network = (
        TemporalPointNet(n_frames=config.temporal_frames, **hparams)
        if temporal
        else PointNetRegressor(**hparams)
    )
    targets = torch.from_numpy(train_batches.targets)
    with torch.no_grad():
        features = torch.cat(
            [network.cloud_features(points) for points, _ in train_batches.batches(256, rng=None)]
        )
    depth_std = (
        float(train_batches.pools[train_batches.frames, :, 3].std()) if config.rest_depth else 1.0
    )
    network.set_normalization(
        targets.mean(0),
        targets.std(0, unbiased=False),
        features.mean(0),
        features.std(0, unbiased=False),
        depth_std,
    )
    return network


def _mean_loss(
    network: PointNetRegressor, batches: FrameBatches, batch_size: int, device: torch.device
) -> tuple[float, float]:
    """(scaled MSE, MAE of the error vector in newtons) over all frames, fixed point draws."""
    network.eval()
    squared, absolute, n = 0.0, 0.0, 0
    with torch.no_grad():
        for points, y in batches.batches(batch_size, rng=None):
            error = network(points.to(device)) - y.to(device)
            squared += float(((error / network.target_std) ** 2).mean(1).sum())
            absolute += float(error.norm(dim=1).sum())
            n += len(y)
    return squared / n, absolute / n


def fit_network(
    network: PointNetRegressor,
    train_batches: FrameBatches,
    check_batches: FrameBatches | None,
    config: TrainConfig,
    epochs: int,
    device: torch.device,
    rng: np.random.Generator,
    deadline: float | None,
    progress: Callable[[int, int, float], None] | None,
    warm_start: bool = False,
    stop_after: int | None = None,
    patience: int | None = None,
) -> FitOutcome:
    """Train ``network`` in place; it ends with the best (or, without validation, last) weights.

    With ``warm_start`` the starting weights compete too (best epoch 0): a network that starts
    from a trained one is never handed back worse on the validation frames than it started.
    ``stop_after``: stop after so many epochs of the ``epochs``-long schedule (a refit without
    validation that stops where a fit with validation found its best epoch; 0 keeps the
    starting weights). ``patience``: epochs without a better validation loss before it stops
    (default ``config.patience``). ``progress(epoch, epochs, best validation loss)`` after
    each epoch.
    """
    patience = config.patience if patience is None else patience
    network.to(device)
    optimizer = torch.optim.NAdam(network.parameters(), lr=config.learning_rate)
    steps_per_epoch = max(
        1,
        sum(
            1
            for k in range(0, len(train_batches), config.batch_size)
            if len(train_batches) - k >= 2
        ),
    )
    total_steps = max(epochs * steps_per_epoch, 1)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: 0.5 * (1.0 + math.cos(math.pi * min(step / total_steps, 1.0)))
    )
    history: list[dict[str, float]] = []
    best_loss, best_epoch, best_state = float("inf"), -1, None
    start: dict[str, float] = {"epoch": 0}
    if warm_start and check_batches is not None:
        start["val_loss"], start["val_mae_n"] = _mean_loss(
            network, check_batches, 4 * config.batch_size, device
        )
        best_loss, best_epoch = start["val_loss"], 0
        best_state = copy.deepcopy(network.state_dict())
    stopped_by = "epochs"
    last = epochs if stop_after is None else min(stop_after, epochs)
    if last < epochs:
        stopped_by = "refit"
    epoch_seconds: list[float] = []
    for epoch in range(1, last + 1):
        clock = time.perf_counter()
        network.train()
        total, count = 0.0, 0
        for points, y in train_batches.batches(config.batch_size, rng):
            if len(y) < 2:  # batch norm needs two samples
                continue
            points, y = points.to(device), y.to(device)
            loss = (((network(points) - y) / network.target_std) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
            total += loss.item() * len(y)
            count += len(y)
            if deadline is not None and time.monotonic() > deadline:
                stopped_by = "time limit"
                break
        entry = {
            "epoch": epoch,
            "train_loss": total / max(count, 1),
            "lr": optimizer.param_groups[0]["lr"],
        }
        if check_batches is not None:
            entry["val_loss"], entry["val_mae_n"] = _mean_loss(
                network, check_batches, 4 * config.batch_size, device
            )
            if entry["val_loss"] < best_loss:
                best_loss, best_epoch = entry["val_loss"], epoch
                best_state = copy.deepcopy(network.state_dict())
        history.append(entry)
        epoch_seconds.append(time.perf_counter() - clock)
        if progress is not None:
            progress(epoch, epochs, best_loss)
        if stopped_by == "time limit":
            break
        if check_batches is not None and epoch - max(best_epoch, 0) >= patience:
            stopped_by = "patience"
            break
    if best_state is None:  # no validation (or no finite validation loss): keep the last epoch
        best_epoch, best_state = len(history), copy.deepcopy(network.state_dict())
    network.load_state_dict(best_state)
    network.to("cpu").eval()
    best = history[best_epoch - 1] if best_epoch else start
    return FitOutcome(
        history=history,
        best_epoch=best_epoch,
        best_val_loss=best.get("val_loss", float("nan")),
        val_mae_n=best.get("val_mae_n", float("nan")),
        stopped_by=stopped_by,
        start_val_loss=start.get("val_loss", float("nan")),
        epoch_seconds=epoch_seconds,
    )
