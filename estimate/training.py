"""Training: every candidate fitted on the training part, the best on held-out trials shipped.

``train`` prepares the sessions, splits them (``splits.py``: by session, by time, by stated
frame ranges), fits the baselines and every candidate (``candidates.py``) on the training
frames, scores all of them on the validation frames (MAE of the force error vector) or, when
the validation part is small (``[train] select_min_val_frames``, or one session), on the
out-of-fold predictions of blocked folds of every session the fit saw, training and validation
(``training_folds``: whole sessions, or blocks in time of a single session with a gap of at
least the force's autocorrelation time; each frame predicted by models fitted without its
session, the networks stopping at the epochs validation chose: no frame that selects or
calibrates a method was fitted, or stopped the fit, of the model predicting it; only the epoch
count comes from the validation sessions); with a validation part, the methods quick to refit
are scored on the out-of-fold predictions of folds of every session the fit saw instead (each
method on its largest held-out set). It selects the method with the lowest held-out MAE, each
protocol's frames weighted equally, among those no worse than the mean predictor on any
protocol's held-out trials (``[train] model = "auto"``; a baseline that beats every candidate
ships instead, and says so) or the one forced (with a warning when it loses to a baseline);
with ``auto`` and held-out trials of several protocols, also each protocol's own method (the
lowest MAE on its trials among those no worse than the mean predictor there), which
evaluation and ``vbfe live`` use for that protocol's frames. It calibrates every method's
prediction interval on the residuals it was scored on (``intervals.py``), fits the flag of
frames outside the training data (``novelty.py``) and writes everything to a model file
(``model_file.py``). With ``folds`` ≥ 3 it first runs blocked cross-validation in time
(``splits.split_folds``): the whole procedure, selection included, per fold, every method
scored (MAE, interval coverage and width) on the fold's test block; the mean ± sd per method
is printed and stored.

Reproducible: epochs and seeds are fixed by the config and torch runs on ``threads`` CPU
threads while training (its reductions are then the same on a loaded or a quiet machine), so
the same command on the same data writes the same model. The time limit only guards: when it
stops a network, a warning says so.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vbfe.common.errors import EstimateError
from vbfe.estimate.baselines import fit_baselines
from vbfe.estimate.candidates import (
    CANDIDATES,
    ENSEMBLE_MEMBERS,
    AnyEstimator,
    MeanEnsemble,
    NetworkEstimator,
    candidate_names,
    fit_texture_hooke,
)
from vbfe.estimate.dataset import (
    FrameBatches,
    PreparedSession,
    ProgressFn,
    prepare_sessions,
    skipped_counts,
)
from vbfe.estimate.disagreement import DisagreementCheck, fit_disagreement
from vbfe.estimate.image_models import RidgeThumbnail, fit_cnn, fit_ridge_thumbnails
from vbfe.estimate.intervals import (
    MIN_PROTOCOL_SESSIONS,
    ConformalInterval,
    calibrate,
    coverage_width,
)
from vbfe.estimate.model_file import ForceModel, save_model
from vbfe.estimate.network_training import build_network, fit_network, resolve_device
from vbfe.estimate.novelty import fit_novelty
from vbfe.estimate.preparation import physical_estimate
from vbfe.estimate.sources import SessionLike
from vbfe.estimate.splits import (
    SessionSplit,
    autocorrelation_frames,
    split_by_ranges,
    split_by_session,
    split_by_time,
    split_folds,
)
from vbfe.estimate.stage_times import STATUS_SEPARATOR, StageTimes
from vbfe.estimate.threads import torch_threads
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.workers import BackgroundPool, Task

log = logging.getLogger(__name__)

MIN_VAL_FRAMES = 8  # fewer validation frames than this: no early stopping

Parts = list[tuple[PreparedSession, np.ndarray]]
# candidates refitted per fold for their intervals (the baselines always are): seconds each
# (the CNN reads a small depth-change image; the ensemble is its mean with Hooke's law)
QUICK_TO_REFIT = tuple(CANDIDATES[k] for k in ("ridge", "hooke_texture", "cnn", "ensemble"))
NETWORKS = (CANDIDATES["pointnet"], CANDIDATES["temporal"])  # minutes per refit
NETWORK_FOLDS = 3  # selection folds of the networks (at most ``select_folds``)


@dataclass
class SplitFit:
    """Every estimator fitted on one split's training part, scored on its validation part."""

    split: SessionSplit
    estimators: dict[str, AnyEstimator]
    val_mae_n: dict[str, float]  # validation MAE (training MAE without validation frames)
    selected: str
    notes: list[str]
    histories: dict[str, Any]
    fit_seconds: dict[str, float]  # wall time of each fit (baselines: all together)
    selection_mae_n: dict[str, float] = field(default_factory=dict)  # what selection read
    intervals: dict[str, dict[str, Any]] = field(default_factory=dict)  # method → interval
    disagreement: DisagreementCheck | None = None  # shipped model against Hooke's law
    # protocol → the method selected on its held-out trials and that method's check
    by_protocol: dict[str, tuple[str, DisagreementCheck | None]] = field(default_factory=dict)


@dataclass
class TrainResult:
    """What a training run produced and how it went."""

    model_path: Path
    split: SessionSplit
    selected: str
    val_mae_n: dict[str, float]  # every method's validation MAE, newtons
    epochs_run: int  # PointNet's (0 when it was not trained)
    best_epoch: int
    history: list[dict[str, float]]
    skipped: dict[str, dict[str, int]]
    duration_s: float
    fit_seconds: dict[str, float] = field(default_factory=dict)  # wall time per fit
    stage_seconds: dict[str, dict[str, float]] = field(default_factory=dict)  # wall, CPU
    device: str = "cpu"  # where the networks trained
    notes: list[str] = field(default_factory=list)
    cross_validation: dict[str, Any] | None = None
    intervals: dict[str, dict[str, Any]] = field(default_factory=dict)  # method → interval
    by_protocol: dict[str, str] = field(default_factory=dict)  # protocol → its method shipped


def use_threads(threads: int) -> None:
    """Set torch's CPU threads (the commands call this for evaluation and live)."""
    if threads > 0:
        torch.set_num_threads(threads)


def make_split(prepared: Sequence[PreparedSession], config: TrainConfig) -> SessionSplit:
    """The split the config states: frame ranges, time (with ``folds``: always), or session."""
    if config.train_frames:
        return split_by_ranges(
            prepared,
            {"train": config.train_frames, "val": config.val_frames, "test": config.test_frames},
        )
    if config.split == "time" or config.folds:
        return split_by_time(prepared, config.val_fraction, config.test_fraction, config.gap_frames)
    return split_by_session(prepared, config.val_fraction, config.test_fraction, config.seed)


def _status(name: str, started: float, best_loss: float) -> str:
    """A candidate's progress label: its time so far and best validation loss."""
    parts = [f"{name} epochs", f"{time.perf_counter() - started:.0f} s"]
    if math.isfinite(best_loss):
        parts.append(f"best val loss {best_loss:.4g}")
    return STATUS_SEPARATOR.join(parts)


def _epoch_progress(
    progress: ProgressFn | None, name: str, started: float
) -> Callable[[int, int, float], None] | None:
    """``progress`` for one candidate's epochs, labelled with :func:`_status`."""
    if progress is None:
        return None
    return lambda done, total, best: progress(_status(name, started, best), done, total)


def _stopping_note(name: str, runs: int, best_epoch: int, stopped_by: str, patience: int) -> str:
    """What early stopping did to one network."""
    if stopped_by == "patience":
        return (
            f"{name}: stopped after {runs} epochs, {patience} without a better validation "
            f"loss; best epoch {best_epoch}"
        )
    return f"{name}: {runs} epochs ({stopped_by}), best epoch {best_epoch}"


def _fit_networks(
    names: list[str],
    train_parts: Parts,
    val_parts: Parts,
    config: TrainConfig,
    progress: ProgressFn | None,
    notes: list[str],
    stop_after: dict[str, int],
    times: StageTimes,
) -> tuple[dict[str, NetworkEstimator], dict[str, Any]]:
    """PointNet, then (when asked) the temporal model started from it; a network named in
    ``stop_after`` stops after so many epochs (a refit where validation found its best)."""
    device = resolve_device(config.device)
    rng = np.random.default_rng(config.seed)
    torch.manual_seed(config.seed)
    windows: dict[str, tuple[int, ...]] = {"pointnet": ()}
    if "temporal" in names:
        windows["temporal"] = tuple(config.temporal_window)
    budget = config.time_limit_s / len(windows)
    fitted: dict[str, NetworkEstimator] = {}
    histories: dict[str, Any] = {}
    for name, window in windows.items():
        started = time.perf_counter()
        train_batches = FrameBatches(train_parts, config.n_points, window)
        check_batches = (
            FrameBatches(val_parts, config.n_points, window, max_frames=config.val_max_frames)
            if val_parts
            else None
        )
        network = build_network(config, train_batches, temporal=bool(window))
        epochs = config.epochs
        if window:  # start as the trained single-frame network, motion correction at zero
            network.load_state_dict(fitted["pointnet"].network.state_dict(), strict=False)
            epochs = config.temporal_epochs or config.epochs
        deadline = time.monotonic() + budget if budget > 0 else None
        patience = config.temporal_patience if window else config.patience
        with times.stage(name):
            outcome = fit_network(
                network,
                train_batches,
                check_batches,
                config,
                epochs,
                device,
                rng,
                deadline,
                _epoch_progress(progress, name, started),
                warm_start=bool(window),
                stop_after=stop_after.get(name),
                patience=patience,
            )
        fitted[name] = NetworkEstimator(network, config.n_points, window, name)
        histories[name] = {
            "fit_s": time.perf_counter() - started,
            "history": outcome.history,
            "best_epoch": outcome.best_epoch,
            "stopped_by": outcome.stopped_by,
            "start_val_loss": outcome.start_val_loss,
            "epoch_seconds": outcome.epoch_seconds,
            "device": str(device),
        }
        if check_batches is not None:
            notes.append(
                _stopping_note(
                    name,
                    len(outcome.history),
                    outcome.best_epoch,
                    outcome.stopped_by,
                    patience,
                )
            )
        if window and outcome.best_epoch == 0:
            notes.append(
                f"{name}: no epoch improved on its start (PointNet's weights, motion "
                "correction at zero) on validation: it is kept as it started and predicts as "
                "pointnet does"
            )
        if outcome.stopped_by == "time limit":
            notes.append(
                f"warning: {name} was stopped by the time limit ({config.time_limit_s:g}"
                f" s) after {len(outcome.history)} of {epochs} epochs: this model "
                "depends on the machine's speed; raise --time-limit or set it to 0"
            )
    return fitted, histories


def best_epochs(histories: dict[str, Any]) -> dict[str, int]:
    """Per network fitted with validation (the CNN's as ``cnn``): the epochs a refit on other
    frames without validation runs, the best epoch (at least 1, except a temporal model whose
    start was best: 0 keeps it as PointNet)."""
    out: dict[str, int] = {}
    for name, h in histories.items():
        entries = h["history"] if isinstance(h, dict) else h
        if not entries or "val_mae_n" not in entries[0]:
            continue  # fitted without validation: a refit runs every epoch
        if name == "cnn":
            out[name] = 1 + int(np.argmin([e["val_mae_n"] for e in entries]))
        else:
            out[name] = h["best_epoch"] if name == "temporal" else max(h["best_epoch"], 1)
    return out


def ridge_choice(estimators: dict[str, AnyEstimator]) -> tuple[int, float] | None:
    """The thumbnail size and penalty the fitted ridge chose (None: no ridge), which its
    refits on other frames keep, as a network's refit keeps its best epoch."""
    ridge = estimators.get(CANDIDATES["ridge"])
    return (ridge.size, ridge.alpha) if isinstance(ridge, RidgeThumbnail) else None


@dataclass(frozen=True)
class Refit:
    """What a refit on other frames keeps from the fit with validation, as a network's refit
    keeps its best epoch: per network the epochs it runs (:func:`best_epochs`; none: all) and
    the ridge's thumbnail size and penalty (:func:`ridge_choice`; None: its own search)."""

    epochs: dict[str, int] = field(default_factory=dict)
    ridge: tuple[int, float] | None = None

    @classmethod
    def of(cls, estimators: dict[str, AnyEstimator], histories: dict[str, Any]) -> Refit:
        """What refits keep of the fits ``estimators`` with their ``histories``."""
        return cls(best_epochs(histories), ridge_choice(estimators))


# called with the estimators and histories so far once the quick methods are fitted
QuickFitted = Callable[[dict[str, AnyEstimator], dict[str, Any]], None]


def _fit_estimators(
    names: list[str],
    train_parts: Parts,
    val_parts: Parts,
    config: TrainConfig,
    progress: ProgressFn | None,
    notes: list[str],
    refit: Refit | None = None,
    times: StageTimes | None = None,
    baselines: bool = True,
    quick_fitted: QuickFitted | None = None,
) -> tuple[dict[str, AnyEstimator], dict[str, Any], dict[str, float]]:
    """The baselines (unless not ``baselines``) and the candidates ``names`` fitted on
    ``train_parts`` (``val_parts``: early stopping; ``refit``: what a refit keeps of the fit
    with validation): the methods quick to fit first, then (after ``quick_fitted``) the
    networks; a candidate that cannot be fitted is taken out of ``names`` with a note."""
    times = times or StageTimes()
    refit = refit or Refit()
    estimators: dict[str, AnyEstimator] = {}
    seconds: dict[str, float] = {}
    if baselines:
        clock = time.perf_counter()
        with times.stage("baselines"):
            estimators.update(fit_baselines(train_parts, config.history_window, config.seed))
        seconds["baselines"] = time.perf_counter() - clock
    histories: dict[str, Any] = {}
    if CANDIDATES["ridge"] in names:
        clock = time.perf_counter()
        with times.stage(CANDIDATES["ridge"]):
            estimators[CANDIDATES["ridge"]] = fit_ridge_thumbnails(
                train_parts, val_parts, config.ridge_sizes, refit.ridge
            )
        seconds[CANDIDATES["ridge"]] = time.perf_counter() - clock
    if {CANDIDATES["cnn"], CANDIDATES["ensemble"]} & set(names):  # the ensemble needs the CNN
        clock = time.perf_counter()
        with times.stage(CANDIDATES["cnn"]):
            cnn, histories["cnn"] = fit_cnn(
                train_parts,
                val_parts,
                config.n_outputs,
                config.cnn_channels,
                refit.epochs.get("cnn", config.cnn_epochs),
                config.seed,
                config.patience,
                _epoch_progress(progress, "cnn", time.perf_counter()),
            )
        estimators[cnn.name] = cnn
        seconds[cnn.name] = time.perf_counter() - clock
        if val_parts:
            runs = len(histories["cnn"])
            best = best_epochs({"cnn": histories["cnn"]})["cnn"]
            stopped = "patience" if runs < config.cnn_epochs else "epochs"
            notes.append(_stopping_note(cnn.name, runs, best, stopped, config.patience))
    if CANDIDATES["ensemble"] in names:
        estimators[CANDIDATES["ensemble"]] = MeanEnsemble(
            tuple(estimators[m] for m in ENSEMBLE_MEMBERS)
        )
    if CANDIDATES["hooke_texture"] in names:
        texture_hooke = fit_texture_hooke(train_parts)
        if texture_hooke is None:
            names.remove(CANDIDATES["hooke_texture"])
            notes.append(
                f"{CANDIDATES['hooke_texture']} skipped: no training frame has a texture"
                " displacement (the clouds carry no colours, or the surface shows no "
                "texture to track)"
            )
            if not names:
                raise EstimateError(
                    "--model hooke_texture needs training clouds with the "
                    "colours of a textured surface; choose another --model"
                )
        else:
            estimators[texture_hooke.name] = texture_hooke
    if quick_fitted is not None:
        quick_fitted(estimators, histories)
    if {"pointnet", "temporal"} & set(names):
        networks, network_histories = _fit_networks(
            names, train_parts, val_parts, config, progress, notes, refit.epochs, times
        )
        estimators.update(networks)
        histories.update(network_histories)
        seconds.update({name: h["fit_s"] for name, h in network_histories.items()})
    return estimators, histories, seconds


def _predictions(estimator: AnyEstimator, parts: Parts, config: TrainConfig) -> np.ndarray:
    """Force (frames × outputs) of the frames of every (session, positions) part, as the
    model file gives it (a magnitude is never below 0 N)."""
    force = np.concatenate([estimator.predict_session(s, p) for s, p in parts])
    return physical_estimate(force, config.target)


def _measured(parts: Parts) -> np.ndarray:
    return np.concatenate([s.targets_n[p] for s, p in parts])


def _frame_labels(parts: Parts) -> np.ndarray:
    """Each frame's protocol and session (rows), in the order of :func:`_measured`."""
    return np.concatenate(
        [np.array([[s.protocol, s.name]] * len(p), dtype=object).reshape(-1, 2) for s, p in parts]
    ).T


def training_folds(parts: Parts, folds: int, gap_frames: int) -> list[tuple[Parts, Parts]]:
    """(training, held-out) parts of blocked folds of ``parts``: whole sessions dealt to
    ``folds`` folds (as many as there are sessions, if fewer), or, with one session, the
    session cut into ``folds`` contiguous blocks in time (``gap_frames``, or the force's
    autocorrelation time when longer, each side of a held-out block left out, at most so many
    that every fold still trains on half the session's frames: a short part is not left with
    nothing to fit)."""
    if len(parts) >= 2:
        n = min(folds, len(parts))
        # dealt in order of protocol and condition: every fold holds a share of each
        order = sorted(
            range(len(parts)), key=lambda i: (parts[i][0].protocol, parts[i][0].condition)
        )
        fold_of = np.empty(len(parts), dtype=np.int64)
        fold_of[order] = np.arange(len(parts)) % n
        return [
            (
                [p for p, f in zip(parts, fold_of, strict=True) if f != k],
                [p for p, f in zip(parts, fold_of, strict=True) if f == k],
            )
            for k in range(n)
        ]
    out = []
    for k in range(folds):
        train: Parts = []
        held: Parts = []
        for session, positions in parts:
            block = np.arange(len(positions)) * folds // max(len(positions), 1)
            # held block n/K plus 2 gaps at most n/2
            gap = max(gap_frames, autocorrelation_frames(session.targets_n[positions]))
            gap = min(gap, len(positions) * (folds - 2) // (4 * folds))
            frames = session.frame_index[positions]
            test = frames[block == k]
            if len(test):
                near = (frames >= test.min() - gap) & (frames <= test.max() + gap)
                held.append((session, positions[block == k]))
                if (~near).any():
                    train.append((session, positions[~near]))
            else:
                train.append((session, positions))
        if train and held:
            out.append((train, held))
    return out


def by_session(parts: Parts) -> Parts:
    """One (session, positions) per session: the positions of all its parts, in order (the
    training and validation ranges of a time split are one recording to fold)."""
    merged: dict[str, tuple[PreparedSession, list[np.ndarray]]] = {}
    for session, positions in parts:
        merged.setdefault(session.name, (session, []))[1].append(positions)
    return [(s, np.unique(np.concatenate(p))) for s, p in merged.values()]


FoldResult = tuple[dict[str, np.ndarray], dict[str, dict[str, float]]]  # predictions, times


def _fold_predictions(
    names: list[str],
    folds: list[tuple[Parts, Parts]],
    config: TrainConfig,
    refit: Refit,
    baselines: bool,
) -> list[FoldResult]:
    """Folds one after the other: ``names`` (and the baselines, with ``baselines``) refitted
    on each fold's training parts with torch on one thread wherever it runs (a worker process
    or the trainer's: the same predictions), their predictions of its held-out parts and the
    refit's stage times."""
    out = []
    with torch_threads(1):
        for fold_train, held in folds:
            times = StageTimes()
            estimators, _, _ = _fit_estimators(
                list(names), fold_train, [], config, None, [], refit, times, baselines
            )
            predicted = {name: _predictions(e, held, config) for name, e in estimators.items()}
            out.append((predicted, times.seconds))
    return out


def _without_pools(parts: Parts) -> Parts:
    """``parts`` without the point pools (only the networks read them): a worker is sent the
    rest, a few kilobytes a frame."""
    return [(dataclasses.replace(s, pools=s.pools[:, :0]), p) for s, p in parts]


@dataclass
class _Folds:
    """A group of methods' fold refits under way: its tasks (each a run of folds), and per
    fold its held-out parts."""

    tasks: list[Task[list[FoldResult]]]
    held: list[Parts]
    group: list[str]


def _start_folds(
    pool: BackgroundPool,
    names: list[str],
    parts: Parts,
    n_folds: int,
    config: TrainConfig,
    refit: Refit,
    baselines: bool,
    fit_cpu_s: float,
    beside_networks: bool = False,
) -> _Folds:
    """Start the refits of ``names`` (and the baselines, with ``baselines``) on ``n_folds``
    blocked folds of ``parts`` (``fit_cpu_s``: the CPU seconds their fit on all of it took;
    folds expected to cost more than workers' start go to the workers). ``beside_networks``:
    the trainer fits its networks meanwhile, so the folds are one task, one worker beside it
    (more workers slowed its networks by more than they gained: PointNet 62 → 86 s beside
    three)."""
    folds = training_folds(parts, n_folds, config.gap_frames)
    if not set(names) & set(NETWORKS):
        folds = [(_without_pools(train), _without_pools(held)) for train, held in folds]
    in_worker = pool.worth_workers(fit_cpu_s * len(folds))
    runs = [folds] if beside_networks else [[fold] for fold in folds]
    tasks = [
        pool.submit(in_worker, _fold_predictions, names, run, config, refit, baselines)
        for run in runs
    ]
    return _Folds(tasks, [held for _, held in folds], names)


def _out_of_fold(
    pool: BackgroundPool,
    started: list[_Folds],
    parts: Parts,
    times: StageTimes,
    what: str,
) -> tuple[dict[str, np.ndarray], Parts, str]:
    """Every method's out-of-fold predictions from the fold refits ``started`` (the first
    group's folds hold out the frames; a group whose folds held out others is left out) over
    ``parts`` (``what`` they are, for the line), the held-out frames in the same order (by
    session, then frame) and a line saying what was done."""
    held_parts = by_session([part for held in started[0].held for part in held])
    order = {key: k for k, key in enumerate(_frame_keys(held_parts))}
    predicted: dict[str, np.ndarray] = {}
    for folds in started:
        fold_predictions: dict[str, list[np.ndarray]] = {}
        for task in folds.tasks:
            for fold, seconds in pool.result(task):
                times.add(seconds)
                for name, force in fold.items():
                    fold_predictions.setdefault(name, []).append(force)
        keys = [key for held in folds.held for key in _frame_keys(held)]
        rows = np.array([order.get(key, -1) for key in keys])
        if len(rows) != len(order) or (rows < 0).any():  # other frames held out: not comparable
            log.warning(
                "%s: its %d folds held out other frames; left out", folds.group, len(folds.held)
            )
            continue
        for name, values in fold_predictions.items():
            if len(values) == len(folds.held):
                stacked = np.concatenate(values)
                predicted[name] = np.empty_like(stacked)
                predicted[name][rows] = stacked
    counts = [len(folds.held) for folds in started]
    kind = "sessions" if len(parts) >= 2 else "blocks in time"
    where = f"{counts[0]} blocked folds of {what} ({kind})"
    if len(counts) > 1 and counts[1] != counts[0]:
        where += f", {counts[1]} for the networks"
    return predicted, held_parts, where


def _frame_keys(parts: Parts) -> list[tuple[str, int]]:
    """(session, position) of every frame of ``parts``, in order."""
    return [(s.name, int(p)) for s, positions in parts for p in positions]


# per method: predicted, measured, the frames' (protocol, session) rows and where they came from
Residuals = dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, str]]


def fit_split(
    prepared: Sequence[PreparedSession],
    split: SessionSplit,
    config: TrainConfig,
    progress: ProgressFn | None = None,
    times: StageTimes | None = None,
) -> SplitFit:
    """Fit baselines and candidates on ``split``'s training part, score each on its largest
    held-out set (validation, or out-of-fold over every session the fit saw: for the methods
    quick to refit, or for all when validation is small), select the shipped model (and one
    per protocol) and calibrate every method's prediction interval on the same residuals."""
    train_parts = split.frames("train", prepared)
    if not train_parts:
        raise EstimateError(
            "the split leaves no training frame; widen --train or lower "
            "--val-fraction/--test-fraction"
        )
    val_parts = split.frames("val", prepared)
    n_val = sum(len(p) for _, p in val_parts)
    notes = [split.describe()]
    if n_val < MIN_VAL_FRAMES:
        notes.append(
            f"warning: too little data for a validation set ({n_val} frames; one "
            f"session, or too few for --val-fraction/--val): no early stopping (fixed "
            f"{config.epochs} epochs, last kept); the MAEs below are training MAEs"
        )
        val_parts = []
    names = candidate_names(config.model, config.temporal_frames > 0)
    times = times or StageTimes()
    if val_parts and not config.early_stopping:
        notes.append(
            "no early stopping ([train] early_stopping = false): every network runs its "
            "epochs; the validation sessions only select and calibrate"
        )
    selection_folds = bool(config.select_min_val_frames) and (
        n_val < config.select_min_val_frames or len(val_parts) < 2
    )
    fitting = by_session(train_parts + val_parts)  # every session the fit saw
    started: list[_Folds] = []
    networks = [n for n in names if n in NETWORKS]
    with BackgroundPool("fold refits", at_least=NETWORK_FOLDS) as pool:

        def start_quick_folds(
            estimators: dict[str, AnyEstimator], histories: dict[str, Any]
        ) -> None:
            """The fold refits of the methods quick to refit, started beside the networks'
            fits: folds of every session the fit saw, for selection when validation is small,
            else for the intervals (holding out about as many sessions as validation does)."""
            if selection_folds:
                group, n_folds = [n for n in names if n not in NETWORKS], config.select_folds
            elif config.interval_folds and val_parts:
                group = [n for n in names if n in QUICK_TO_REFIT]
                n_val_sessions = len({s.name for s, _ in val_parts})
                n_folds = min(config.select_folds, max(3, round(len(fitting) / n_val_sessions)))
            else:
                return
            refit = Refit.of(estimators, histories)
            cpu_s = sum(v["cpu_s"] for k, v in times.seconds.items() if k in ("baselines", *group))
            beside = bool(networks)  # the trainer fits them next
            started.append(
                _start_folds(pool, group, fitting, n_folds, config, refit, True, cpu_s, beside)
            )

        estimators, histories, seconds = _fit_estimators(
            names,
            train_parts,
            val_parts if config.early_stopping else [],
            config,
            progress,
            notes,
            times=times,
            quick_fitted=start_quick_folds,
        )
        if selection_folds and networks:
            started.append(
                _start_folds(
                    pool,
                    networks,
                    fitting,
                    min(config.select_folds, NETWORK_FOLDS),
                    config,
                    Refit.of(estimators, histories),
                    False,
                    sum(times.seconds[n]["cpu_s"] for n in networks),
                )
            )
        check = val_parts or train_parts
        val_mae = {
            name: float(
                np.linalg.norm(_predictions(e, check, config) - _measured(check), axis=1).mean()
            )
            for name, e in estimators.items()
        }
        folded: tuple[dict[str, np.ndarray], Parts, str] | None = None
        if started:
            what = "the training and validation sessions" if val_parts else "the training part"
            stage = "selection folds" if selection_folds else "interval folds"
            with times.parts(stage) as fold_times:
                folded = _out_of_fold(pool, started, fitting, fold_times, what)
    held: dict[str, np.ndarray] = {}
    held_parts: Parts = []
    where = "validation"
    if selection_folds and folded is not None:
        held, held_parts, where = folded
        notes.append(
            f"validation part small ({n_val} frames from {len(val_parts)} session(s), under "
            f"{config.select_min_val_frames} frames or 2 sessions): selection and intervals "
            f"on {where}"
        )
    elif val_parts:
        held = {name: _predictions(e, val_parts, config) for name, e in estimators.items()}
        held_parts = val_parts
    measured = _measured(held_parts) if held_parts else np.zeros((0, config.n_outputs))
    labels = _frame_labels(held_parts) if held_parts else np.zeros((2, 0), dtype=object)
    residuals: Residuals = {name: (p, measured, labels, where) for name, p in held.items()}
    if not selection_folds and folded is not None:  # the quick methods' interval folds
        quick, quick_parts, quick_where = folded
        quick_measured, quick_labels = _measured(quick_parts), _frame_labels(quick_parts)
        residuals.update(
            {
                n: (p, quick_measured, quick_labels, quick_where)
                for n, p in quick.items()
                if n in residuals
            }
        )
        if quick:  # each method scored on its largest held-out set
            where = (
                f"held-out trials ({quick_where} for the methods quick to refit, validation "
                "for the others)"
            )
    by_protocol = {
        n: held_out_mae({n: p}, m, rows[0])[n] for n, (p, m, rows, _) in residuals.items()
    }
    scores = {n: float(np.mean(list(v.values()))) for n, v in by_protocol.items()}
    if not any(n in scores for n in names):
        scores, where = val_mae, "validation" if val_parts else "training"
        by_protocol = {n: {"": v} for n, v in scores.items()}
        notes.append(
            "warning: no held-out frames to select on or to calibrate intervals with: "
            f"selected on {where}, no intervals"
        )
    scored = [n for n in names if n in scores]
    auto = config.model == "auto"
    ranked = _ranked(residuals, by_protocol) if auto else set(by_protocol)
    if not any(n in ranked for n in scored):
        ranked = set(by_protocol)
    rank = {n: v for n, v in by_protocol.items() if n in ranked}
    chosen = [n for n in scored if n in ranked]
    selected, note = select(chosen, {n: scores[n] for n in rank}, rank, where, auto)
    per_protocol = select_per_protocol(chosen, rank) if auto else {}
    if per_protocol:
        note += "; per protocol (its frames say which): " + ", ".join(
            f"{p} {n} {by_protocol[n][p]:.3f} N" for p, n in per_protocol.items()
        )
    if unranked := sorted(set(by_protocol) - ranked):
        note += (
            f"; not ranked, held out on fewer sessions of a protocol than the others: "
            f"{', '.join(unranked)}"
        )
    log.info("%s", note)
    notes.append(note)
    notes.append(
        f"held-out MAE per method on {where} (N; protocols weighted equally): "
        + ", ".join(
            f"{n} {scores[n]:.3f}"
            + (
                " (" + ", ".join(f"{p} {v:.3f}" for p, v in by_protocol[n].items()) + ")"
                if len(by_protocol[n]) > 1
                else ""
            )
            for n in sorted(scores, key=scores.__getitem__)
        )
    )
    intervals = {
        name: calibrate(
            p, m, config.interval_coverage, config.interval_scale, source, *rows
        ).to_dict()
        for name, (p, m, rows, source) in residuals.items()
    }

    def hooke_check(method: str, protocol: str | None = None) -> DisagreementCheck | None:
        """The method's check against Hooke's law on the held-out frames (of ``protocol``)."""
        if method not in intervals:
            return None
        rows = labels[0] == protocol if protocol is not None else slice(None)
        return fit_disagreement(method, {n: p[rows] for n, p in held.items()})

    return SplitFit(
        split,
        estimators,
        val_mae,
        selected,
        notes,
        histories,
        seconds,
        scores,
        intervals,
        hooke_check(selected),
        {p: (n, hooke_check(n, p)) for p, n in per_protocol.items()},
    )


def _ranked(residuals: Residuals, by_protocol: dict[str, dict[str, float]]) -> set[str]:
    """The methods held out on as many sessions of each protocol as a protocol's own interval
    needs (``MIN_PROTOCOL_SESSIONS``), or as the most any method was: one validation trial
    does not rank a method against others scored out of fold over several (the quick demo's
    temporal model, best on its one freehand validation trial at 0.233 N against the
    ensemble's 0.271 N over two, erred 0.704 N on the held-out trial, the mean predictor
    0.472 N)."""
    sessions = {
        n: {p: len(set(rows[1][rows[0] == p].tolist())) for p in by_protocol[n]}
        for n, (_, _, rows, _) in residuals.items()
        if n in by_protocol
    }
    need = {
        p: min(MIN_PROTOCOL_SESSIONS, max(s.get(p, 0) for s in [{}, *sessions.values()]))
        for v in by_protocol.values()
        for p in v
    }
    return {
        n
        for n, v in by_protocol.items()
        if all(sessions.get(n, {}).get(p, 0) >= need[p] for p in v)
    }


def held_out_mae(
    held: dict[str, np.ndarray], measured: np.ndarray, protocols: np.ndarray
) -> dict[str, dict[str, float]]:
    """Per method, the MAE of its held-out predictions within each protocol."""
    names = sorted(set(protocols.tolist()), key=str)
    return {
        method: {
            str(p): float(np.linalg.norm(force - measured, axis=1)[protocols == p].mean())
            for p in names
        }
        for method, force in held.items()
    }


def select(
    names: list[str],
    scores: dict[str, float],
    by_protocol: dict[str, dict[str, float]],
    where: str,
    auto: bool,
) -> tuple[str, str]:
    """The method shipped and a line saying which and why.

    ``scores``: every method's held-out MAE, each protocol weighted equally (``by_protocol``:
    per protocol). With ``auto`` the method with the lowest score ships among those no worse
    than the mean predictor in any protocol (the mean predictor itself always is): a baseline
    that beats every candidate ships, and a candidate that beats the mean on one protocol's
    trials but loses on another's does not. A forced model ships with a warning when it loses
    to a baseline.
    """
    best = min(names, key=lambda name: scores[name])
    baselines = {n: v for n, v in scores.items() if n not in CANDIDATES.values()}
    best_baseline = min(baselines, key=lambda n: baselines[n])
    if not auto:
        line = f"selected model: {best} (forced by --model), {where} MAE {scores[best]:.3f} N"
        if scores[best] <= baselines[best_baseline]:
            return best, f"{line}; best baseline {best_baseline} {baselines[best_baseline]:.3f} N"
        return best, (
            f"warning: {line} LOSES to the baseline {best_baseline} "
            f"({baselines[best_baseline]:.3f} N on {where})"
        )
    mean = by_protocol.get("mean", {})

    def no_worse_than_mean(method: str) -> bool:
        return all(v <= mean.get(p, np.inf) for p, v in by_protocol[method].items())

    eligible = [n for n in [*names, *baselines] if no_worse_than_mean(n)] or list(baselines)
    shipped = min(eligible, key=lambda name: scores[name])
    losing = [
        f"{n} {scores[n]:.3f} N"
        for n in names
        if not no_worse_than_mean(n) and scores[n] < scores[shipped]
    ]
    why = (
        f"; better on the mean of the protocols but worse than the mean predictor on one "
        f"protocol's trials, not shipped: {', '.join(losing)}"
        if losing
        else ""
    )
    line = (
        f"selected model: {shipped} (lowest MAE on {where}, of {len(names)} candidates and "
        f"{len(baselines)} baselines, never worse than the mean predictor on any protocol), "
        f"{scores[shipped]:.3f} N"
    )
    if shipped in names:
        return shipped, (
            f"{line}; best baseline {best_baseline} {baselines[best_baseline]:.3f} N{why}"
        )
    return shipped, (
        f"warning: the best candidate {best} ({scores[best]:.3f} N on {where}) LOSES to "
        f"the baseline {shipped}: {line}{why}; force a candidate with --model to ship it anyway"
    )


def select_per_protocol(
    names: list[str], by_protocol: dict[str, dict[str, float]]
) -> dict[str, str]:
    """Where the held-out frames are of several protocols, the method shipped for each: the
    lowest MAE on that protocol's held-out frames among the methods (``names`` and the
    baselines) no worse there than the mean predictor (a live run or an evaluation of one
    protocol's sessions uses it; a mix of protocols, the one model for all)."""
    protocols = sorted({p for v in by_protocol.values() for p in v})
    if len(protocols) < 2:
        return {}
    baselines = [n for n in by_protocol if n not in CANDIDATES.values()]
    methods = [n for n in [*names, *baselines] if n in by_protocol]
    mean = by_protocol.get("mean", {})
    eligible = {
        p: [n for n in methods if by_protocol[n].get(p, np.inf) <= mean.get(p, np.inf)]
        for p in protocols
    }
    return {p: min(ns, key=lambda n: by_protocol[n][p]) for p, ns in eligible.items() if ns}


def cross_validate(
    prepared: Sequence[PreparedSession], config: TrainConfig, progress: ProgressFn | None = None
) -> dict[str, Any]:
    """Blocked K-fold cross-validation in time: per fold the whole fit and selection, every
    method's test MAE; summary mean ± sd per method (``selected``: whatever each fold chose)."""
    folds: list[dict[str, Any]] = []
    splits = split_folds(prepared, config.folds, config.gap_frames)
    for k, split in enumerate(splits):
        fit = fit_split(prepared, split, config)
        test = split.frames("test", prepared)
        measured = _measured(test)
        mae, covered = {}, {}
        for name, estimator in fit.estimators.items():
            predicted = _predictions(estimator, test, config)
            mae[name] = float(np.linalg.norm(predicted - measured, axis=1).mean())
            if name in fit.intervals:
                interval = ConformalInterval.from_dict(fit.intervals[name])
                bounds = interval.bounds(predicted, _frame_labels(test)[0])
                covered[name] = coverage_width(*bounds, measured)
        mae["selected"] = mae[fit.selected]
        if fit.selected in covered:
            covered["selected"] = covered[fit.selected]
        folds.append(
            {
                "split": split.to_dict(),
                "description": split.describe(),
                "selected": fit.selected,
                "test_mae_n": mae,
                "test_interval": covered,
                "n_test_frames": int(len(measured)),
                "n_train_frames": sum(len(f) for _, f in split.frames("train", prepared)),
            }
        )
        if progress is not None:
            progress("folds", k + 1, len(splits))
    methods = list(folds[0]["test_mae_n"])
    summary: dict[str, dict[str, float]] = {
        m: {
            "mean_mae_n": float(np.mean([f["test_mae_n"][m] for f in folds])),
            "sd_mae_n": float(np.std([f["test_mae_n"][m] for f in folds], ddof=1)),
        }
        for m in methods
    }
    for m in methods:  # interval coverage pooled over the folds' test frames
        weights = [f["n_test_frames"] for f in folds if m in f["test_interval"]]
        if len(weights) == len(folds):
            for key in ("interval_coverage", "interval_width_n"):
                values = [f["test_interval"][m][key] for f in folds]
                summary[m][key] = float(np.average(values, weights=weights))
    return {"folds": folds, "summary": summary, "gap_frames": config.gap_frames}


def train(
    sessions: Sequence[SessionLike],
    out: str | Path,
    config: TrainConfig | None = None,
    progress: ProgressFn | None = None,
) -> TrainResult:
    """Train on sessions (paths with clouds, imported clouds files, or ``SessionClouds``) and
    write the model file to ``out``.

    ``progress(stage, done, total)`` is called per prepared session (``"sessions"``), per
    epoch of each network (``"pointnet epochs · 12 s · best val loss 0.31"``: the part
    before ``" · "`` names the stage, the rest is its time so far and best validation loss;
    ``temporal``, ``cnn``) and per cross-validation fold (``"folds"``).
    Torch runs on ``config.threads`` threads inside and the caller's count is restored.
    """
    config = config or TrainConfig()
    started = time.monotonic()
    times = StageTimes()
    device = resolve_device(config.device)  # a --device torch cannot use: refused before work
    with torch_threads(config.threads), torch.random.fork_rng(devices=[]):
        # tracking the texture triples a frame's preparation: only for the candidate reading it
        texture = CANDIDATES["hooke_texture"] in candidate_names(
            config.model, config.temporal_frames > 0
        )
        with times.stage("preparation"):
            prepared = prepare_sessions(sessions, config, progress, texture)
        if len({s.name for s in prepared}) != len(prepared):
            raise EstimateError("the same session was given twice; give each session once")
        cv = None
        if config.folds:
            with times.stage("cross-validation"):
                cv = cross_validate(prepared, config, progress)
        fit = fit_split(prepared, make_split(prepared, config), config, progress, times)
    skipped = skipped_counts(prepared)
    shipped = {p: n for p, (n, _) in fit.by_protocol.items()}
    pointnet = fit.histories.get("pointnet", {"history": [], "best_epoch": 0})
    record = {
        "split": fit.split.to_dict(),
        "split_description": fit.split.describe(),
        "selected": fit.selected,
        "selected_by_protocol": shipped,
        "validation_mae_n": fit.val_mae_n,
        "selection_mae_n": fit.selection_mae_n,
        "intervals": fit.intervals,
        "notes": fit.notes,
        "histories": fit.histories,
        "fit_seconds": fit.fit_seconds,
        "stage_seconds": times.seconds,
        "skipped": skipped,
        "threads": config.threads,
        "device": str(device),
        "conditions": {s.name: s.conditions for s in prepared},
        "cross_validation": cv,
    }
    model = ForceModel(
        config=config,
        estimators=fit.estimators,
        selected=fit.selected,
        record=record,
        novelty=fit_novelty(
            by_session(fit.split.frames("train", prepared) + fit.split.frames("val", prepared))
        ),
        disagreement=fit.disagreement,
        by_protocol=fit.by_protocol,
    )
    path = save_model(out, model)
    return TrainResult(
        model_path=path,
        split=fit.split,
        selected=fit.selected,
        val_mae_n=fit.val_mae_n,
        epochs_run=len(pointnet["history"]),
        best_epoch=pointnet["best_epoch"],
        history=pointnet["history"],
        skipped=skipped,
        duration_s=time.monotonic() - started,
        fit_seconds=fit.fit_seconds,
        stage_seconds=times.seconds,
        device=str(device),
        notes=fit.notes,
        cross_validation=cv,
        intervals=fit.intervals,
        by_protocol=shipped,
    )
