"""Estimators that read each frame as an image: its depth change against the rest frame.

- ``ridge_height_map``: ridge regression on a ``size × size`` thumbnail of the depth-change
  image (``depth_image.thumbnails``), columns standardised on the training frames. The size
  and the penalty are chosen together on the validation frames (without them, by blocked
  cross-validation over the training frames: one fold per session, or contiguous blocks).
- ``cnn_depth_change``: a small convolutional network on the full depth-change image (two
  channels: the change scaled by its training spread, and where points were seen), seeded,
  CPU-sized (thousands of weights), trained with Adam for up to ``cnn_epochs`` keeping the
  epoch with the lowest validation MAE, stopped ``patience`` epochs after it.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from vbfe.estimate.dataset import PreparedSession
from vbfe.estimate.depth_image import thumbnails

Parts = Sequence[tuple[PreparedSession, np.ndarray]]
RIDGE = "ridge_height_map"  # the ridge candidate's method name
RIDGE_FOLDS = 5
CNN_BATCH = 32
CNN_LEARNING_RATE = 3e-3
CNN_WEIGHT_DECAY = 1e-4
CNN_HIDDEN = 32


def _positions(session: PreparedSession, positions: np.ndarray | None) -> np.ndarray:
    return np.arange(session.n_used) if positions is None else np.asarray(positions)


@dataclass(frozen=True)
class RidgeThumbnail:
    """Force = ((thumbnail − mean) / scale) · weights + intercept."""

    name: str
    size: int
    mean: np.ndarray  # size²
    scale: np.ndarray  # size²
    weights: np.ndarray  # size² × outputs
    intercept: np.ndarray  # outputs
    alpha: float

    def predict(self, x: np.ndarray) -> np.ndarray:
        """Predicted force (frames × outputs) from thumbnails (frames × size²)."""
        return ((np.asarray(x, float) - self.mean) / self.scale) @ self.weights + self.intercept

    def predict_session(
        self, session: PreparedSession, positions: np.ndarray | None = None
    ) -> np.ndarray:
        """Predicted force (frames × outputs) of a prepared session's used frames."""
        p = _positions(session, positions)
        return self.predict(thumbnails(session.image_sum[p], session.image_count[p], self.size))

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": "ridge",
            "size": self.size,
            "mean": self.mean.tolist(),
            "scale": self.scale.tolist(),
            "weights": self.weights.tolist(),
            "intercept": self.intercept.tolist(),
            "alpha": self.alpha,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RidgeThumbnail:
        return cls(
            d["name"],
            int(d["size"]),
            mean=np.asarray(d["mean"], float),
            scale=np.asarray(d["scale"], float),
            weights=np.asarray(d["weights"], float),
            intercept=np.asarray(d["intercept"], float),
            alpha=float(d["alpha"]),
        )


def _thin_svd(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.linalg.svd(x, full_matrices=False)`` without the (near) zero singular values, from
    the eigenvectors of the smaller Gram matrix (frames × frames or columns × columns): many
    times faster than LAPACK's SVD of the tall or wide matrix."""
    wide = x.shape[0] < x.shape[1]
    eigenvalues, vectors = np.linalg.eigh(x @ x.T if wide else x.T @ x)
    keep = eigenvalues > max(float(eigenvalues[-1]), 0.0) * 1e-12
    sv = np.sqrt(eigenvalues[keep])
    vectors = vectors[:, keep]
    if wide:
        return vectors, sv, (x.T @ vectors / sv).T
    return x @ vectors / sv, sv, vectors.T


def _ridge_solve(
    x: np.ndarray, y: np.ndarray, alphas: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """Column means and scales of ``x``, the mean of ``y`` and ridge weights for every alpha."""
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale = np.where(scale > 1e-12, scale, 1.0)
    u, sv, vt = _thin_svd((x - mean) / scale)
    y_mean = y.mean(axis=0)
    uty = u.T @ (y - y_mean)
    return mean, scale, y_mean, [vt.T @ ((sv / (sv**2 + a))[:, None] * uty) for a in alphas]


def _alphas(n_frames: int, n_columns: int) -> np.ndarray:
    return np.logspace(-2, 5, 22) * n_frames / max(n_columns, 1)


def _check_errors(
    x_fit: np.ndarray,
    y_fit: np.ndarray,
    x_check: np.ndarray,
    y_check: np.ndarray,
    alphas: np.ndarray,
) -> np.ndarray:
    """Summed absolute (vector) error on the check frames of a fit for every alpha."""
    mean, scale, y_mean, weights = _ridge_solve(x_fit, y_fit, alphas)
    x = (x_check - mean) / scale
    return np.array([np.linalg.norm(x @ w + y_mean - y_check, axis=1).sum() for w in weights])


def _blocked_folds(n: int, groups: np.ndarray | None) -> list[np.ndarray]:
    """The penalty's check folds: whole sessions dealt into at most ``RIDGE_FOLDS`` folds (as
    scikit-learn's ``GroupKFold``; one per session cost the full demo's 5 interval folds 42 s
    of ridge solves over 16 sessions each), else contiguous blocks of frames."""
    frames = np.arange(n)
    if groups is not None and len(np.unique(groups)) >= 2:
        sessions = np.unique(groups)
        dealt = [sessions[k::RIDGE_FOLDS] for k in range(min(RIDGE_FOLDS, len(sessions)))]
        return [frames[np.isin(groups, fold)] for fold in dealt]
    return np.array_split(frames, min(RIDGE_FOLDS, n))


def fit_ridge(
    x: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray | None = None,
    x_val: np.ndarray | None = None,
    y_val: np.ndarray | None = None,
    name: str = RIDGE,
    size: int = 0,
) -> tuple[RidgeThumbnail, float]:
    """Ridge on ``x`` (frames × columns) with the penalty chosen on the validation frames, or
    without them by blocked cross-validation (``groups``: a session id per frame, one fold per
    session; else contiguous folds). Returns the fit and its mean check error."""
    alphas = _alphas(len(x), x.shape[1])
    if x_val is not None and y_val is not None and len(x_val):
        errors, n_check = _check_errors(x, y, x_val, y_val, alphas), len(x_val)
    else:
        errors, n_check = np.zeros(len(alphas)), 0
        for fold in _blocked_folds(len(x), groups):
            fit = np.setdiff1d(np.arange(len(x)), fold)
            if len(fit) >= 2:
                errors += _check_errors(x[fit], y[fit], x[fold], y[fold], alphas)
                n_check += len(fold)
    best = int(np.argmin(errors))
    mean, scale, y_mean, weights = _ridge_solve(x, y, alphas[best : best + 1])
    return (
        RidgeThumbnail(name, size, mean, scale, weights[0], y_mean, float(alphas[best])),
        float(errors[best] / max(n_check, 1)),
    )


def fit_ridge_thumbnails(
    train: Parts, val: Parts, sizes: Sequence[int], choice: tuple[int, float] | None = None
) -> RidgeThumbnail:
    """The ridge of the thumbnail size and penalty with the lowest validation MAE, or, with
    ``choice``, of that (size, penalty): a refit where validation chose them (the full
    demo's interval folds: 14 s of penalty searches down to one solve each)."""

    def stack(parts: Parts, size: int) -> np.ndarray:
        return np.concatenate(
            [thumbnails(s.image_sum[p], s.image_count[p], size) for s, p in parts]
        )

    y = np.concatenate([s.targets_n[p] for s, p in train])
    if choice is not None:
        size, alpha = choice
        mean, scale, y_mean, weights = _ridge_solve(stack(train, size), y, np.array([alpha]))
        return RidgeThumbnail(RIDGE, size, mean, scale, weights[0], y_mean, alpha)
    groups = np.concatenate([np.full(len(p), k) for k, (_, p) in enumerate(train)])
    y_val = np.concatenate([s.targets_n[p] for s, p in val]) if val else None
    fits = [
        fit_ridge(
            stack(train, size), y, groups, stack(val, size) if val else None, y_val, size=size
        )
        for size in sizes
    ]
    return min(fits, key=lambda fit: fit[1])[0]


class DepthCNN(nn.Module):
    """Depth-change image (B × 2 × cells × cells: scaled change, seen mask) → force (newtons)."""

    # buffers (register_buffer), saved with the weights
    change_scale: torch.Tensor
    target_mean: torch.Tensor
    target_std: torch.Tensor

    def __init__(self, n_outputs: int = 1, channels: Sequence[int] = (8, 16, 32)) -> None:
        super().__init__()
        self.hparams = {"n_outputs": n_outputs, "channels": list(channels)}
        layers: list[nn.Module] = []
        for c_in, c_out in zip([2, *channels[:-1]], channels, strict=False):
            layers += [nn.Conv2d(c_in, c_out, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2)]
        self.features = nn.Sequential(*layers, nn.AdaptiveAvgPool2d(2), nn.Flatten())
        self.head = nn.Sequential(
            nn.Linear(4 * channels[-1], CNN_HIDDEN), nn.ReLU(), nn.Linear(CNN_HIDDEN, n_outputs)
        )
        self.register_buffer("change_scale", torch.ones(1))
        self.register_buffer("target_mean", torch.zeros(n_outputs))
        self.register_buffer("target_std", torch.ones(n_outputs))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(images)) * self.target_std + self.target_mean

    def inputs(self, sums: np.ndarray, counts: np.ndarray) -> torch.Tensor:
        """The network's input from depth-change images (frames × cells × cells sums, counts)."""
        change = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
        x = np.stack([change / float(self.change_scale), counts > 0], axis=1)
        return torch.from_numpy(x.astype(np.float32))


@dataclass
class CnnEstimator:
    """The trained ``DepthCNN`` as an estimator of prepared sessions."""

    network: DepthCNN
    name: str = "cnn_depth_change"

    def predict_session(
        self, session: PreparedSession, positions: np.ndarray | None = None
    ) -> np.ndarray:
        """Predicted force (frames × outputs) of a prepared session's used frames."""
        p = _positions(session, positions)
        self.network.eval()
        with torch.no_grad():
            return (
                self.network(self.network.inputs(session.image_sum[p], session.image_count[p]))
                .double()
                .numpy()
            )

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": "cnn",
            "hparams": self.network.hparams,
            "state_dict": self.network.state_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CnnEstimator:
        network = DepthCNN(**d["hparams"])
        network.load_state_dict(d["state_dict"])
        return cls(network.eval(), d["name"])


def _images(parts: Parts) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (
        np.concatenate([s.image_sum[p] for s, p in parts]),
        np.concatenate([s.image_count[p] for s, p in parts]),
        np.concatenate([s.targets_n[p] for s, p in parts]).astype(np.float32),
    )


def fit_cnn(
    train: Parts,
    val: Parts,
    n_outputs: int,
    channels: Sequence[int],
    epochs: int,
    seed: int,
    patience: int | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> tuple[CnnEstimator, list[dict[str, float]]]:
    """Train the CNN on the training frames for up to ``epochs``, keeping the epoch of lowest
    validation MAE and stopping ``patience`` epochs after it (without validation frames: all
    ``epochs``, the last kept); seeded without touching torch's global random state."""
    sums, counts, y = _images(train)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        network = DepthCNN(n_outputs, channels)
    seen = counts > 0
    change = sums[seen] / counts[seen]
    network.change_scale.fill_(max(float(change.std()) if len(change) else 0.0, 1e-9))
    network.target_mean.copy_(torch.from_numpy(y.mean(0)))
    network.target_std.copy_(torch.from_numpy(np.maximum(y.std(0), 1e-6)))
    x, targets = network.inputs(sums, counts), torch.from_numpy(y)
    check = _images(val) if val else None
    x_check = network.inputs(*check[:2]) if check else None
    optimizer = torch.optim.Adam(
        network.parameters(), CNN_LEARNING_RATE, weight_decay=CNN_WEIGHT_DECAY
    )
    generator = torch.Generator().manual_seed(seed)
    best, best_epoch, best_state, history = float("inf"), 0, None, []
    for epoch in range(1, epochs + 1):
        network.train()
        for index in torch.randperm(len(x), generator=generator).split(CNN_BATCH):
            loss = (((network(x[index]) - targets[index]) / network.target_std) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        entry: dict[str, float] = {"epoch": epoch}
        if check is not None:
            network.eval()
            with torch.no_grad():
                error = (network(x_check) - torch.from_numpy(check[2])).norm(dim=1)
            entry["val_mae_n"] = float(error.mean())
            if entry["val_mae_n"] < best:
                best, best_epoch = entry["val_mae_n"], epoch
                best_state = copy.deepcopy(network.state_dict())
        history.append(entry)
        if progress is not None:
            progress(epoch, epochs, best)
        if check is not None and patience is not None and epoch - best_epoch >= patience:
            break
    if best_state is not None:
        network.load_state_dict(best_state)
    return CnnEstimator(network.eval()), history
