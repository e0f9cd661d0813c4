"""The trained-model file: network weights plus everything needed to use and audit them.

A model file is ``torch.save`` of a plain dict (loadable with ``weights_only=True``): format
name and version, architecture name and version, network hyper-parameters and weights (force
scaling and global-feature standardisation are buffers of the network), the training config,
the session split (kind, gap, blocks), the fitted baselines, training history, skipped-frame
counts and the vbfe version that wrote it; with a temporal model also its hyper-parameters
(window size k in ``n_frames``) and weights under ``temporal``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vbfe import __version__
from vbfe.config import ConfigError
from vbfe.estimate.baselines import Baseline, baseline_from_dict
from vbfe.estimate.dataset import (MIN_FRAME_POINTS, FrameBatches, PreparedSession,
                                   SessionSplit, crop_roi, sample_points)
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.pointnet import (ARCHITECTURE, ARCHITECTURE_VERSION, PointNetRegressor,
                                    TemporalPointNet)
from vbfe.estimate.rest_depth import RestDepth
from vbfe.estimate.train_config import TrainConfig
from vbfe.files import atomic_path
from vbfe.settings import parse_kwargs, parse_table

FORMAT = "vbfe-force-model"
FORMAT_VERSION = 1


@dataclass
class ForceModel:
    """A trained regressor with its config, baselines and training record."""

    network: PointNetRegressor
    config: TrainConfig
    baselines: dict[str, Baseline]
    record: dict[str, Any] = field(default_factory=dict)  # split, sessions, history, versions
    temporal: TemporalPointNet | None = None

    @property
    def split(self) -> SessionSplit:
        """The split the model was trained with."""
        return SessionSplit.from_dict(self.record.get("split", {}))

    def predict_points(self, points: np.ndarray | torch.Tensor) -> np.ndarray:
        """Force (B×outputs, N) for clouds already prepared (B×n_points×C, metres; see
        ``prepare_cloud``)."""
        self.network.eval()
        device = next(self.network.parameters()).device
        with torch.no_grad():
            return self.network(torch.as_tensor(points, dtype=torch.float32,
                                                device=device)).cpu().numpy()

    def rest_reference(self, rest_points: np.ndarray) -> RestDepth | None:
        """The rest reference for clouds of one run, from its rest (undeformed) cloud (N×3,
        may hold NaN; cropped to the training ROI); ``None`` when the network needs none."""
        if not self.network.rest_depth:
            return None
        cropped = crop_roi(rest_points, self.config)
        if len(cropped) < MIN_FRAME_POINTS:
            raise EstimateError(f"the rest cloud has {len(cropped)} points inside the model's "
                                "region of interest; start from a frame where the tissue is "
                                "seen at rest")
        return RestDepth(cropped)

    def prepare_cloud(self, points: np.ndarray, rng: np.random.Generator,
                      rest: RestDepth | None = None) -> np.ndarray:
        """A raw cloud (N×3, may hold NaN) cropped to the training ROI and sampled to
        ``n_points`` (n_points×3, or ×4 with the depth change against ``rest``, which a
        network trained with ``rest_depth`` needs)."""
        cropped = crop_roi(points, self.config)
        if len(cropped) == 0:
            raise EstimateError("the cloud has no finite point inside the model's region of "
                                "interest; check the reconstruction or the [train] roi")
        sampled = sample_points(cropped, self.config.n_points, rng)
        if not self.network.rest_depth:
            return sampled
        if rest is None:
            raise EstimateError("this model reads each cloud against the rest cloud of its "
                                "run; give the rest (undeformed) cloud")
        return rest.with_change(sampled)

    def predict_cloud(self, points: np.ndarray, seed: int = 0,
                      rest_points: np.ndarray | None = None) -> np.ndarray:
        """Force (outputs,) for one raw cloud (N×3, may hold NaN); applies the training ROI.
        ``rest_points``: the run's rest cloud (needed when the network uses ``rest_depth``)."""
        rest = self.rest_reference(rest_points) if rest_points is not None else None
        sampled = self.prepare_cloud(points, np.random.default_rng(seed), rest)
        return self.predict_points(sampled[None])[0]

    def predict_session(self, session: PreparedSession, batch_size: int = 64) -> np.ndarray:
        """Force (frames×outputs) for every used frame of a prepared session."""
        return self._predict_frames(self.network, session, (), batch_size)

    def predict_session_temporal(self, session: PreparedSession, batch_size: int = 16
                                 ) -> np.ndarray:
        """Temporal-model force (frames×outputs) for every used frame of a prepared session."""
        if self.temporal is None:
            raise EstimateError("this model file has no temporal model: train with "
                                "temporal_frames >= 2 in [train]")
        return self._predict_frames(self.temporal, session, self.config.temporal_window,
                                    batch_size)

    def _predict_frames(self, network: PointNetRegressor, session: PreparedSession,
                        window: Sequence[int], batch_size: int) -> np.ndarray:
        frames = FrameBatches([(session, np.arange(session.n_used))], self.config.n_points,
                              window)
        network.eval()
        with torch.no_grad():
            return np.concatenate([network(points).numpy()
                                   for points, _ in frames.batches(batch_size, rng=None)])


def save_model(path: str | Path, model: ForceModel) -> Path:
    """Write the model file atomically (a temporary file renamed into place)."""
    path = Path(path)
    payload = {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "architecture": ARCHITECTURE, "architecture_version": ARCHITECTURE_VERSION,
        "vbfe_version": __version__, "created_unix_ns": time.time_ns(),
        "hparams": model.network.hparams, "state_dict": model.network.state_dict(),
        "config": model.config.to_dict(),
        "baselines": {name: b.to_dict() for name, b in model.baselines.items()},
        "record": model.record,
        "temporal": None if model.temporal is None else {
            "hparams": model.temporal.hparams, "state_dict": model.temporal.state_dict()},
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def _check(payload: Any, path: Path, key: str, expected: Any, what: str) -> None:
    if payload.get(key) != expected:
        raise EstimateError(f"{path} is a {what} {payload.get(key)!r} model, this vbfe "
                            f"{__version__} reads {what} {expected!r}: retrain with `vbfe train`")


def load_model(path: str | Path) -> ForceModel:
    """Read a model file written by ``save_model``; other files raise ``EstimateError``."""
    path = Path(path)
    if not path.is_file():
        raise EstimateError(f"model file {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for foreign files; all mean "not a model"
        raise EstimateError(f"{path} is not a vbfe model file ({type(exc).__name__}); "
                            "give the .pt file written by `vbfe train`") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise EstimateError(f"{path} is not a vbfe model file; give the .pt file written by "
                            "`vbfe train`")
    _check(payload, path, "format_version", FORMAT_VERSION, "format version")
    _check(payload, path, "architecture", ARCHITECTURE, "architecture")
    _check(payload, path, "architecture_version", ARCHITECTURE_VERSION, "architecture version")
    return _model_from_payload(payload, path)


_PAYLOAD_TYPES = {"hparams": dict, "state_dict": dict, "config": dict, "baselines": dict,
                  "record": dict}


def _model_from_payload(payload: dict[str, Any], path: Path) -> ForceModel:
    """Check every part of a model file's payload and build the model; EstimateError if bad."""
    retrain = "retrain with `vbfe train` or give the .pt file it wrote"
    for key, kind in _PAYLOAD_TYPES.items():
        if not isinstance(payload.get(key), kind):
            raise EstimateError(f"{path} has no valid {key!r} entry (damaged model file); "
                                f"{retrain}")
    try:
        network = PointNetRegressor(**parse_kwargs(PointNetRegressor, payload["hparams"],
                                                   "hparams"))
        config = parse_table(TrainConfig, payload["config"], "train")
    except (ConfigError, EstimateError, ValueError, TypeError) as exc:
        raise EstimateError(f"{path}: model settings are damaged: {exc}; {retrain}") from None
    state = payload["state_dict"]
    bad = [k for k, v in state.items() if not isinstance(v, torch.Tensor)
           or (v.is_floating_point() and not torch.isfinite(v).all())]
    if bad:
        raise EstimateError(f"{path}: weight {bad[0]!r} is not finite or not a tensor "
                            f"(damaged model file); {retrain}")
    try:
        network.load_state_dict(state)
    except RuntimeError as exc:
        first = str(exc).splitlines()[1].strip() if "\n" in str(exc) else str(exc)
        raise EstimateError(f"{path}: the weights do not fit the network ({first[:200]}); "
                            f"{retrain}") from None
    network.eval()
    temporal = None
    try:
        if payload.get("temporal"):
            temporal = TemporalPointNet(**payload["temporal"]["hparams"])
            temporal.load_state_dict(payload["temporal"]["state_dict"])
            temporal.eval()
    except (KeyError, TypeError, ValueError, RuntimeError):
        raise EstimateError(f"{path}: the temporal model is damaged; {retrain}") from None
    try:
        baselines = {name: baseline_from_dict(b) for name, b in payload["baselines"].items()}
    except (KeyError, TypeError, ValueError, AttributeError):
        raise EstimateError(f"{path}: the baselines are damaged; {retrain}") from None
    record = dict(payload["record"])
    record["vbfe_version"] = payload.get("vbfe_version")
    return ForceModel(network=network, config=config, baselines=baselines, record=record,
                      temporal=temporal)

