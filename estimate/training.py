"""Training the PointNet force regressor (and the temporal model) on recorded or in-memory sessions.

``train`` prepares the sessions, splits them (by session or by time blocks, see
``dataset.split_sessions``), fits the baselines on the training frames, trains with NAdam on an
MSE loss (force scaled by its training standard deviation) under a per-step cosine learning
rate, keeps the network of the epoch with the lowest validation loss (measured on a fixed
validation subsample with fixed point draws) and writes everything to a model file (see
``model_file.py``). Without enough validation frames it says so, trains the configured number
of epochs and keeps the last. The time limit is checked after every batch, where the
schedule's length is also re-sized to the steps the remaining time allows, so the learning
rate anneals by the time limit.
With ``temporal_frames > 0`` the temporal model is trained the same way after PointNet
(each gets half of the time limit), starting as the trained PointNet with its motion
correction at zero, for ``temporal_epochs``; its starting weights compete in the best-epoch
choice, so on the validation frames it is never worse than PointNet.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from vbfe.estimate.baselines import fit_baselines
from vbfe.estimate.dataset import (FrameBatches, PreparedSession, ProgressFn, SessionSplit,
                                   prepare_sessions, skipped_counts, split_sessions)
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.model_file import ForceModel, save_model
from vbfe.estimate.pointnet import PointNetRegressor, TemporalPointNet
from vbfe.estimate.sources import SessionLike
from vbfe.estimate.train_config import TrainConfig

MIN_VAL_FRAMES = 8  # fewer validation frames than this: no early stopping


@dataclass
class FitOutcome:
    """How one network's training went."""

    history: list[dict[str, float]]
    best_epoch: int
    best_val_loss: float
    val_mae_n: float
    stopped_by: str  # "epochs", "patience" or "time limit"
    start_val_loss: float = float("nan")  # of the starting weights (warm start only)


@dataclass
class TrainResult:
    """What a training run produced and how it went."""

    model_path: Path
    split: SessionSplit
    epochs_run: int
    best_epoch: int
    best_val_loss: float  # MSE of force / training force std (dimensionless)
    val_mae_n: float  # PointNet MAE on the validation frames (training frames if none)
    baseline_val_mae_n: dict[str, float]
    history: list[dict[str, float]]
    skipped: dict[str, dict[str, int]]
    duration_s: float
    temporal_val_mae_n: float | None = None
    notes: list[str] = field(default_factory=list)


def resolve_device(name: str) -> torch.device:
    """``auto`` → CUDA when torch sees a GPU, else CPU; ``cuda`` without a GPU is an error."""
    if name == "cuda" and not torch.cuda.is_available():
        raise EstimateError("--device cuda: torch sees no CUDA device here; use --device cpu "
                            "or auto")
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    return torch.device(name)


def use_threads(threads: int) -> None:
    """Set torch's CPU threads from the config (the commands call this; ``train`` does not)."""
    if threads > 0:
        torch.set_num_threads(threads)


def _build_network(config: TrainConfig, train_batches: FrameBatches,
                   temporal: bool) -> PointNetRegressor:
    hparams = dict(n_outputs=config.n_outputs, conv_channels=config.conv_channels,
                   head_channels=config.head_channels, dropout=config.dropout,
                   global_features=config.global_features, rest_depth=config.rest_depth)
    network = (TemporalPointNet(n_frames=config.temporal_frames, **hparams) if temporal
               else PointNetRegressor(**hparams))
    targets = torch.from_numpy(train_batches.targets)
    with torch.no_grad():
        features = torch.cat([network.cloud_features(points)
                              for points, _ in train_batches.batches(256, rng=None)])
    depth_std = (float(train_batches.pools[train_batches.frames, :, 3].std())
                 if config.rest_depth else 1.0)
    network.set_normalization(targets.mean(0), targets.std(0, unbiased=False),
                              features.mean(0), features.std(0, unbiased=False), depth_std)
    return network


def _mean_loss(network: PointNetRegressor, batches: FrameBatches, batch_size: int,
               device: torch.device) -> tuple[float, float]:
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


class _CosineSteps:
    """Per-step cosine learning-rate factor whose total number of steps can be re-sized."""

    def __init__(self, total_steps: int) -> None:
        self.total_steps = max(total_steps, 1)

    def __call__(self, step: int) -> float:
        return 0.5 * (1.0 + math.cos(math.pi * min(step / self.total_steps, 1.0)))


def _fit(network: PointNetRegressor, train_batches: FrameBatches,
         check_batches: FrameBatches | None, config: TrainConfig, epochs: int,
         device: torch.device, rng: np.random.Generator, deadline: float | None,
         progress: Callable[[int, int], None] | None, warm_start: bool = False) -> FitOutcome:
    """Train ``network`` in place; it ends with the best (or, without validation, last) weights.

    With ``warm_start`` the starting weights compete too (best epoch 0): a network that starts
    from a trained one is never handed back worse on the validation frames than it started.
    """
    network.to(device)
    optimizer = torch.optim.NAdam(network.parameters(), lr=config.learning_rate)
    steps_per_epoch = max(1, sum(1 for k in range(0, len(train_batches), config.batch_size)
                                 if len(train_batches) - k >= 2))
    planned_steps = epochs * steps_per_epoch
    cosine = _CosineSteps(planned_steps)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, cosine)
    history: list[dict[str, float]] = []
    best_loss, best_epoch, best_state = float("inf"), -1, None
    start = {"epoch": 0}
    if warm_start and check_batches is not None:
        start["val_loss"], start["val_mae_n"] = _mean_loss(
            network, check_batches, 4 * config.batch_size, device)
        best_loss, best_epoch = start["val_loss"], 0
        best_state = copy.deepcopy(network.state_dict())
    stopped_by, steps = "epochs", 0
    fit_start = time.monotonic()  # per-step time below includes the validation passes
    for epoch in range(1, epochs + 1):
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
            steps += 1
            total += loss.item() * len(y)
            count += len(y)
            if deadline is not None:
                now = time.monotonic()
                if now > deadline:
                    stopped_by = "time limit"
                    break
                # anneal over the steps the remaining time allows, re-sized after every step
                step_s = (now - fit_start) / steps
                affordable = steps + int((deadline - now) / step_s)
                cosine.total_steps = max(min(planned_steps, affordable), steps, 1)
        entry = {"epoch": epoch, "train_loss": total / max(count, 1),
                 "lr": optimizer.param_groups[0]["lr"]}
        if check_batches is not None:
            entry["val_loss"], entry["val_mae_n"] = _mean_loss(
                network, check_batches, 4 * config.batch_size, device)
            if entry["val_loss"] < best_loss:
                best_loss, best_epoch = entry["val_loss"], epoch
                best_state = copy.deepcopy(network.state_dict())
        history.append(entry)
        if progress is not None:
            progress(epoch, epochs)
        if stopped_by == "time limit":
            break
        if check_batches is not None and epoch - max(best_epoch, 0) >= config.patience:
            stopped_by = "patience"
            break
    if best_state is None:  # no validation (or no finite validation loss): keep the last epoch
        best_epoch, best_state = len(history), copy.deepcopy(network.state_dict())
    network.load_state_dict(best_state)
    network.to("cpu").eval()
    best = history[best_epoch - 1] if best_epoch else start
    return FitOutcome(history=history, best_epoch=best_epoch,
                      best_val_loss=best.get("val_loss", float("nan")),
                      val_mae_n=best.get("val_mae_n", float("nan")), stopped_by=stopped_by,
                      start_val_loss=start.get("val_loss", float("nan")))


def _frames_mae(predict: Callable[[PreparedSession], np.ndarray],
                parts: Sequence[tuple[PreparedSession, np.ndarray]]) -> float:
    errors = [np.linalg.norm(predict(s)[p] - s.targets_n[p], axis=1) for s, p in parts]
    return float(np.concatenate(errors).mean())


def train(sessions: Sequence[SessionLike], out: str | Path, config: TrainConfig | None = None,
          progress: ProgressFn | None = None) -> TrainResult:
    """Train a force regressor on sessions (paths with clouds, imported clouds files, or
    ``SessionClouds``).

    ``progress(stage, done, total)`` is called per prepared session (stage ``"sessions"``) and
    per epoch (``"epochs"``, then ``"temporal epochs"``). Returns a ``TrainResult``; the model
    is written to ``out``. Torch's thread count is left as the caller set it.
    """
    config = config or TrainConfig()
    started = time.monotonic()
    device = resolve_device(config.device)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)

    prepared = prepare_sessions(sessions, config, progress)
    by_name = {s.name: s for s in prepared}
    if len(by_name) != len(prepared):
        raise EstimateError("the same session was given twice; give each session once")
    split = split_sessions(prepared, config)
    train_parts = split.frames("train", prepared)
    val_parts = split.frames("val", prepared)
    n_val = sum(len(p) for _, p in val_parts)
    notes = [split.describe()]
    if n_val < MIN_VAL_FRAMES:
        notes.append(f"warning: too little data for a validation set ({n_val} frames; one "
                     f"session, or too few for --val-fraction): no early stopping, trained the "
                     f"fixed {config.epochs} epochs and kept the last; the MAE below is the "
                     f"training MAE")
        val_parts = []
    baselines = fit_baselines(train_parts, config.history_window, config.seed)
    check_parts = val_parts or train_parts

    budget = config.time_limit_s / (2 if config.temporal_frames else 1)
    windows = {"pointnet": ()}
    if config.temporal_frames:
        windows["temporal"] = config.temporal_window
    networks, outcomes = {}, {}
    for name, window in windows.items():
        train_batches = FrameBatches(train_parts, config.n_points, window)
        check_batches = (FrameBatches(val_parts, config.n_points, window,
                                      max_frames=config.val_max_frames) if val_parts else None)
        network = _build_network(config, train_batches, temporal=bool(window))
        epochs, stage = config.epochs, "epochs"
        if window:  # start as the trained single-frame network, motion correction at zero
            network.load_state_dict(networks["pointnet"].state_dict(), strict=False)
            epochs, stage = config.temporal_epochs or config.epochs, "temporal epochs"
        deadline = time.monotonic() + budget if budget > 0 else None
        outcomes[name] = _fit(network, train_batches, check_batches, config, epochs, device,
                              rng, deadline, (lambda done, total, stage=stage:
                                              progress(stage, done, total)) if progress else None,
                              warm_start=bool(window))
        networks[name] = network
        if outcomes[name].stopped_by == "time limit":
            notes.append(f"{name}: stopped by the time limit after "
                         f"{len(outcomes[name].history)} epoch(s)")

    skipped = skipped_counts(prepared)
    pointnet = outcomes["pointnet"]
    record = {
        "split": split.to_dict(), "split_description": split.describe(),
        "early_stopping_on": "val" if val_parts else "none (too little validation data)",
        "device": str(device), "notes": notes,
        "normalization": {"target_mean_n": networks["pointnet"].target_mean.tolist(),
                          "target_std_n": networks["pointnet"].target_std.tolist()},
        "history": pointnet.history, "best_epoch": pointnet.best_epoch, "skipped": skipped,
        "conditions": {s.name: s.conditions for s in prepared},
    }
    if "temporal" in outcomes:
        record["temporal"] = {"window": config.temporal_window,
                              "history": outcomes["temporal"].history,
                              "best_epoch": outcomes["temporal"].best_epoch,
                              "start_val_loss": outcomes["temporal"].start_val_loss}
    model = ForceModel(networks["pointnet"], config, baselines, record,
                       temporal=networks.get("temporal"))
    path = save_model(out, model)
    method_mae = {name: _frames_mae(b.predict_session, check_parts)
                  for name, b in baselines.items()}
    temporal_mae = (_frames_mae(model.predict_session_temporal, check_parts)
                    if model.temporal is not None else None)
    return TrainResult(
        model_path=path, split=split, epochs_run=len(pointnet.history),
        best_epoch=pointnet.best_epoch, best_val_loss=pointnet.best_val_loss,
        val_mae_n=_frames_mae(model.predict_session, check_parts),
        baseline_val_mae_n=method_mae, history=pointnet.history, skipped=skipped,
        duration_s=time.monotonic() - started, temporal_val_mae_n=temporal_mae, notes=notes)
