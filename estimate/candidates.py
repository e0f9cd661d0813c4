"""The estimators that compete to be the shipped model, and how each is stored.

Candidates (``--model`` name → method name in reports): ``pointnet`` (the paper's network,
the reference method), ``temporal`` (PointNet over a causal window, when ``temporal_frames``
≥ 2), ``ridge`` (``ridge_height_map``) and ``cnn`` (``cnn_depth_change``), the last two on the
depth-change image (``image_models.py``), ``ensemble`` (``ensemble_cnn_hooke``): the mean of
the CNN's and Hooke's law's forces, and ``hooke_texture`` (``hooke_texture_3d``): Hooke's law
on the peak 3D displacement tracked in the tissue's texture (``texture_motion.py``). The CNN and
Hooke err on different trials (the CNN where the image looks unlike its training trials, Hooke
where the visible depth change under-reads a pull that is mostly sideways): their mean errs
less than either unless one of them fails. Tracking the texture sees the sideways part of a
pull; without colours or texture in the training clouds that candidate is skipped.
Every estimator, candidate or baseline, answers ``predict_session(session, positions=None)``
and ``to_dict()``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from vbfe.common.errors import EstimateError
from vbfe.estimate.baselines import FITTERS, AffineBaseline, Baseline, baseline_from_dict
from vbfe.estimate.dataset import FrameBatches, PreparedSession
from vbfe.estimate.image_models import CnnEstimator, RidgeThumbnail
from vbfe.estimate.pointnet import PointNetRegressor, TemporalPointNet

CANDIDATES = {
    "pointnet": "pointnet",
    "temporal": "temporal",
    "ridge": "ridge_height_map",
    "cnn": "cnn_depth_change",
    "ensemble": "ensemble_cnn_hooke",
    "hooke_texture": "hooke_texture_3d",
}
TEXTURE_FEATURE = "texture_displacement_m"
ENSEMBLE_MEMBERS = (CANDIDATES["cnn"], "hooke")


@dataclass
class NetworkEstimator:
    """PointNet (``window`` empty) or the temporal model (``window``: offsets back) on the
    first ``n_points`` of each frame's pool (fixed draws)."""

    network: PointNetRegressor
    n_points: int
    window: tuple[int, ...] = ()
    name: str = "pointnet"

    def predict_session(
        self, session: PreparedSession, positions: np.ndarray | None = None, batch_size: int = 32
    ) -> np.ndarray:
        """Force (frames × outputs) of a prepared session's used frames."""
        p = np.arange(session.n_used) if positions is None else np.asarray(positions)
        frames = FrameBatches([(session, p)], self.n_points, self.window)
        self.network.eval()
        device = next(self.network.parameters()).device
        with torch.no_grad():
            return np.concatenate(
                [
                    self.network(points.to(device)).cpu().double().numpy()
                    for points, _ in frames.batches(batch_size, rng=None)
                ]
            )

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": "network",
            "hparams": self.network.hparams,
            "state_dict": self.network.state_dict(),
            "n_points": self.n_points,
            "window": list(self.window),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NetworkEstimator:
        kind = TemporalPointNet if "n_frames" in d["hparams"] else PointNetRegressor
        network = kind(**d["hparams"])
        state = d["state_dict"]
        bad = [
            k
            for k, v in state.items()
            if not isinstance(v, torch.Tensor)
            or (v.is_floating_point() and not torch.isfinite(v).all())
        ]
        if bad:
            raise EstimateError(f"weight {bad[0]!r} is not finite or not a tensor")
        network.load_state_dict(state)
        return cls(
            network.eval(), int(d["n_points"]), tuple(int(o) for o in d["window"]), d["name"]
        )


@dataclass
class MeanEnsemble:
    """The mean of its members' forces (each stored whole, so the ensemble stands alone)."""

    members: tuple[Any, ...]
    name: str = CANDIDATES["ensemble"]

    def predict_session(
        self, session: PreparedSession, positions: np.ndarray | None = None
    ) -> np.ndarray:
        """Force (frames × outputs) of a prepared session's used frames."""
        return np.mean([m.predict_session(session, positions) for m in self.members], axis=0)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": "ensemble",
            "members": [m.to_dict() for m in self.members],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MeanEnsemble:
        if not d.get("members"):
            raise EstimateError(f"ensemble {d.get('name')!r} has no members")
        return cls(tuple(estimator_from_dict(m) for m in d["members"]), d["name"])


AnyEstimator = NetworkEstimator | RidgeThumbnail | CnnEstimator | MeanEnsemble | Baseline
_KINDS: dict[str, Callable[[dict[str, Any]], AnyEstimator]] = {
    "network": NetworkEstimator.from_dict,
    "ridge": RidgeThumbnail.from_dict,
    "cnn": CnnEstimator.from_dict,
    "ensemble": MeanEnsemble.from_dict,
}


def estimator_from_dict(d: dict[str, Any]) -> AnyEstimator:
    """Rebuild an estimator stored by its ``to_dict``."""
    return _KINDS.get(str(d.get("kind")), baseline_from_dict)(d)


def candidate_names(model: str, temporal: bool) -> list[str]:
    """Method names to fit for ``--model`` (``auto``: all; temporal only when configured)."""
    if model == "auto":
        return [name for key, name in CANDIDATES.items() if key != "temporal" or temporal]
    if model == "temporal" and not temporal:
        raise EstimateError("--model temporal needs temporal_frames >= 2 (--temporal-frames)")
    return [CANDIDATES[model]]


def fit_texture_hooke(parts: list[tuple[PreparedSession, np.ndarray]]) -> AffineBaseline | None:
    """Hooke's law on the texture's 3D displacement over the training frames that have one;
    ``None`` when none has (clouds without colours, or an untextured surface)."""
    d = np.concatenate([s.texture_displacement_m[p] for s, p in parts])
    if not np.isfinite(d).any():
        return None
    y = np.concatenate([s.targets_n[p] for s, p in parts])
    return AffineBaseline(CANDIDATES["hooke_texture"], *FITTERS["hooke"](d, y), TEXTURE_FEATURE)


def reads_texture(estimator: AnyEstimator) -> bool:
    """Whether an estimator (or a member of it) reads the texture displacement."""
    members = getattr(estimator, "members", ())
    return getattr(estimator, "feature", None) == TEXTURE_FEATURE or any(
        reads_texture(m) for m in members
    )
