"""Displacement-history baseline: a small MLP on a causal window of peak displacements.

A frame's input is the session's peak surface displacement (``PreparedSession.displacement_m``)
at ``offsets`` used frames back (0: the frame itself). Frames before the session's first frame
count as the rest state (0), and so do frames without a displacement, as in the affine
baselines. One frame cannot tell a slow pull of a stiff tissue from a fast pull of a soft one
at the same displacement, nor a hold from a pull; the displacement's recent course can. Two
ReLU layers of ``HIDDEN`` units, fitted full-batch with Adam on the training frames only,
seeded, without touching torch's global random state.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from vbfe.estimate.dataset import PreparedSession
from vbfe.estimate.threads import torch_threads

HIDDEN = 64
STEPS = 2000
LEARNING_RATE = 3e-3
WEIGHT_DECAY = 1e-4


def history_features(displacement_m: np.ndarray, offsets: Sequence[int]) -> np.ndarray:
    """Frames × offsets: the displacement ``offset`` frames back (0 before the first frame)."""
    d = np.nan_to_num(np.asarray(displacement_m, np.float64), nan=0.0)
    n = len(d)
    columns = [np.concatenate([np.zeros(min(o, n)), d[: max(n - o, 0)]]) for o in offsets]
    return np.stack(columns, axis=1)


@dataclass(frozen=True)
class HistoryBaseline:
    """Force = MLP((history − x_mean) / x_scale) + y_mean, the MLP's layers as numpy arrays."""

    name: str
    offsets: tuple[int, ...]
    x_mean: np.ndarray  # offsets
    x_scale: np.ndarray  # offsets
    y_mean: np.ndarray  # outputs
    layers: tuple[tuple[np.ndarray, np.ndarray], ...]  # (weight out×in, bias out) per layer

    def predict(self, history_m: np.ndarray) -> np.ndarray:
        """Predicted force (frames × outputs) from displacement histories (frames × offsets)."""
        h = (np.asarray(history_m, np.float64) - self.x_mean) / self.x_scale
        for k, (weight, bias) in enumerate(self.layers):
            h = h @ weight.T + bias
            if k < len(self.layers) - 1:
                h = np.maximum(h, 0.0)
        return h + self.y_mean

    def predict_session(
        self, session: PreparedSession, positions: np.ndarray | None = None
    ) -> np.ndarray:
        """Predicted force (used frames × outputs) of a prepared session."""
        history = history_features(session.displacement_m, self.offsets)
        return self.predict(history if positions is None else history[positions])

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": "history_mlp",
            "offsets": list(self.offsets),
            "x_mean": self.x_mean.tolist(),
            "x_scale": self.x_scale.tolist(),
            "y_mean": self.y_mean.tolist(),
            "layers": [[w.tolist(), b.tolist()] for w, b in self.layers],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> HistoryBaseline:
        layers = tuple((np.asarray(w, float), np.asarray(b, float)) for w, b in d["layers"])
        return cls(
            d["name"],
            tuple(int(o) for o in d["offsets"]),
            x_mean=np.asarray(d["x_mean"], float),
            x_scale=np.asarray(d["x_scale"], float),
            y_mean=np.asarray(d["y_mean"], float),
            layers=layers,
        )


def fit_history(
    parts: Sequence[tuple[PreparedSession, np.ndarray]],
    offsets: Sequence[int],
    seed: int = 0,
    steps: int = STEPS,
) -> HistoryBaseline:
    """Fit the MLP on the given (training) frames: (session, used-frame positions)."""
    x = np.concatenate([history_features(s.displacement_m, offsets)[p] for s, p in parts])
    y = np.concatenate([s.targets_n[p] for s, p in parts])
    x_mean, y_mean = x.mean(axis=0), y.mean(axis=0)
    x_scale = x.std(axis=0)
    x_scale = np.where(x_scale > 1e-12, x_scale, 1.0)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        network = nn.Sequential(
            nn.Linear(len(offsets), HIDDEN),
            nn.ReLU(),
            nn.Linear(HIDDEN, HIDDEN),
            nn.ReLU(),
            nn.Linear(HIDDEN, y.shape[1]),
        )
    inputs = torch.from_numpy(((x - x_mean) / x_scale).astype(np.float32))
    targets = torch.from_numpy((y - y_mean).astype(np.float32))
    optimizer = torch.optim.Adam(network.parameters(), LEARNING_RATE, weight_decay=WEIGHT_DECAY)
    with torch_threads(1):  # steps of microseconds: a second thread adds only its overhead
        for _ in range(steps):
            optimizer.zero_grad()
            loss = nn.functional.smooth_l1_loss(network(inputs), targets)
            loss.backward()
            optimizer.step()
    layers = tuple(
        (m.weight.detach().double().numpy(), m.bias.detach().double().numpy())
        for m in network
        if isinstance(m, nn.Linear)
    )
    return HistoryBaseline(
        "mlp_displacement_history", tuple(int(o) for o in offsets), x_mean, x_scale, y_mean, layers
    )
