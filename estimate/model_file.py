"""The trained-model file: every fitted estimator, the one selected, and how they were chosen.

A model file is ``torch.save`` of a plain dict (loadable with ``weights_only=True``): format
name and version, the vbfe version, the training config, every fitted estimator (candidates and
baselines, each as its ``to_dict``: networks as hyper-parameters and weights), the name of the
selected one (and, where the training held out trials of several protocols, the one selected
for each protocol with its check against Hooke's law), a training record (split as frame
ranges, every method's validation MAE, the selection and its warnings, every method's
prediction interval, histories, skipped-frame counts, cross-validation when run), the flag of
frames outside the training data and the check of the shipped model against Hooke's law
(``disagreement.py``). Files written before the intervals, the flag, the check or the
per-protocol selection load without them.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vbfe.common.errors import ConfigError, EstimateError
from vbfe.common.files import atomic_path
from vbfe.common.settings import parse_table
from vbfe.common.version import __version__
from vbfe.estimate.candidates import CANDIDATES, AnyEstimator, estimator_from_dict
from vbfe.estimate.dataset import DEFAULT_PROTOCOL, PreparedSession
from vbfe.estimate.disagreement import DisagreementCheck
from vbfe.estimate.intervals import ConformalInterval
from vbfe.estimate.novelty import NoveltyFlag
from vbfe.estimate.preparation import physical_estimate
from vbfe.estimate.splits import SessionSplit
from vbfe.estimate.train_config import TrainConfig

FORMAT = "vbfe-force-model"
FORMAT_VERSION = 2


@dataclass
class ForceModel:
    """Fitted estimators with the selected one, the training config and record."""

    config: TrainConfig
    estimators: dict[str, AnyEstimator]  # method name → estimator (candidates and baselines)
    selected: str  # the method name shipped (used by evaluate's summary and vbfe live)
    record: dict[str, Any] = field(default_factory=dict)
    novelty: NoveltyFlag | None = None  # flags frames outside the training data
    disagreement: DisagreementCheck | None = None  # flags the shipped model off Hooke's law
    # protocol → the method selected on its held-out trials and that method's check
    by_protocol: dict[str, tuple[str, DisagreementCheck | None]] = field(default_factory=dict)

    def for_protocol(self, protocol: str | None) -> ForceModel:
        """The model as it ships for frames of ``protocol`` (``None``: a session stating none,
        :data:`DEFAULT_PROTOCOL`, as training labels it): the method selected on that
        protocol's held-out trials (itself when it selected none for it)."""
        method, check = self.by_protocol.get(
            protocol or DEFAULT_PROTOCOL, (self.selected, self.disagreement)
        )
        return dataclasses.replace(self, selected=method, disagreement=check)

    def interval(self, method: str | None = None) -> ConformalInterval | None:
        """The prediction interval of the selected (or the named) method, if calibrated."""
        stored = self.record.get("intervals", {}).get(method or self.selected)
        return ConformalInterval.from_dict(stored) if stored else None

    @property
    def split(self) -> SessionSplit:
        """The split the model was trained with."""
        return SessionSplit.from_dict(self.record.get("split", {}))

    @property
    def baselines(self) -> dict[str, AnyEstimator]:
        """The fitted baselines (estimators that are not candidates)."""
        return {n: e for n, e in self.estimators.items() if n not in CANDIDATES.values()}

    def predict_session(
        self,
        session: PreparedSession,
        method: str | None = None,
        positions: np.ndarray | None = None,
    ) -> np.ndarray:
        """Force (frames × outputs) of the selected (or the named) method (a magnitude is
        never below 0 N)."""
        name = method or self.selected
        if name not in self.estimators:
            raise EstimateError(
                f"this model file has no {name!r} estimator; it has {', '.join(self.estimators)}"
            )
        force = self.estimators[name].predict_session(session, positions)
        return physical_estimate(force, self.config.target)

    def flagged(self, novelty_m: np.ndarray, forces: dict[str, np.ndarray]) -> np.ndarray:
        """Per frame, whether its estimate is flagged: the frame lies outside the training
        data (``novelty_m`` over the flag's threshold) or the shipped model disagrees with
        Hooke's law (``forces``: frames × outputs of the selected method, its interval
        ``<selected>_lo``/``_hi`` when it has one, and the check's reference)."""
        novelty = np.asarray(novelty_m, np.float64)
        out = novelty > (self.novelty.threshold if self.novelty is not None else np.inf)
        if self.disagreement is not None:
            check, name = self.disagreement, self.selected
            out |= check.flags(
                forces[name],
                forces[check.reference],
                forces.get(f"{name}_lo"),
                forces.get(f"{name}_hi"),
            )
        return out


def save_model(path: str | Path, model: ForceModel) -> Path:
    """Write the model file atomically (a temporary file renamed into place)."""
    path = Path(path)
    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "vbfe_version": __version__,
        "created_unix_ns": time.time_ns(),
        "config": model.config.to_dict(),
        "estimators": {name: e.to_dict() for name, e in model.estimators.items()},
        "selected": model.selected,
        "record": model.record,
    }
    if model.novelty is not None:
        payload["novelty"] = model.novelty.to_dict()
    if model.disagreement is not None:
        payload["disagreement"] = model.disagreement.to_dict()
    if model.by_protocol:
        payload["by_protocol"] = {
            protocol: {"selected": method, "disagreement": check and check.to_dict()}
            for protocol, (method, check) in model.by_protocol.items()
        }
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def load_model(path: str | Path) -> ForceModel:
    """Read a model file written by ``save_model``; other files raise ``EstimateError``."""
    path = Path(path)
    if not path.is_file():
        raise EstimateError(f"model file {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for foreign files; all mean "not a model"
        raise EstimateError(
            f"{path} is not a vbfe model file ({type(exc).__name__}); "
            "give the .pt file written by `vbfe train`"
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise EstimateError(
            f"{path} is not a vbfe model file; give the .pt file written by `vbfe train`"
        )
    if payload.get("format_version") != FORMAT_VERSION:
        raise EstimateError(
            f"{path} is a format version {payload.get('format_version')!r} "
            f"model, this vbfe {__version__} reads format version "
            f"{FORMAT_VERSION}: retrain with `vbfe train`"
        )
    return _model_from_payload(payload, path)


_PAYLOAD_TYPES = {"config": dict, "estimators": dict, "record": dict, "selected": str}


def _model_from_payload(payload: dict[str, Any], path: Path) -> ForceModel:
    """Check every part of a model file's payload and build the model; EstimateError if bad."""
    retrain = "retrain with `vbfe train` or give the .pt file it wrote"
    for key, kind in _PAYLOAD_TYPES.items():
        if not isinstance(payload.get(key), kind):
            raise EstimateError(
                f"{path} has no valid {key!r} entry (damaged model file); {retrain}"
            )
    try:
        config = parse_table(TrainConfig, payload["config"], "train")
    except (ConfigError, EstimateError, ValueError, TypeError) as exc:
        raise EstimateError(f"{path}: model settings are damaged: {exc}; {retrain}") from None
    estimators = {}
    for name, stored in payload["estimators"].items():
        try:
            estimators[name] = estimator_from_dict(stored)
        except (
            EstimateError,
            KeyError,
            TypeError,
            ValueError,
            AttributeError,
            RuntimeError,
        ) as exc:
            first = str(exc).splitlines()[0][:200]
            raise EstimateError(
                f"{path}: the {name} estimator is damaged ({first}); {retrain}"
            ) from None
    if payload["selected"] not in estimators:
        raise EstimateError(
            f"{path}: the selected model {payload['selected']!r} is missing "
            f"(damaged model file); {retrain}"
        )
    record = dict(payload["record"])
    record["vbfe_version"] = payload.get("vbfe_version")
    try:
        novelty = NoveltyFlag.from_dict(payload["novelty"]) if "novelty" in payload else None
        check = _check(payload.get("disagreement"))
        by_protocol = {
            str(protocol): (str(entry["selected"]), _check(entry["disagreement"]))
            for protocol, entry in payload.get("by_protocol", {}).items()
        }
        for method, _ in by_protocol.values():  # the pooled one is checked above
            if method not in estimators:
                raise EstimateError(f"the selected {method!r} is not among the estimators")
        for each in [check, *(c for _, c in by_protocol.values())]:
            if each is not None and each.reference not in estimators:
                raise EstimateError(f"its reference {each.reference!r} is not an estimator")
        model = ForceModel(
            config, estimators, payload["selected"], record, novelty, check, by_protocol
        )
        for shipped in [model, *map(model.for_protocol, by_protocol)]:
            shipped.interval()
    except (EstimateError, KeyError, TypeError, ValueError) as exc:
        raise EstimateError(
            f"{path}: the intervals, the novelty flag or the disagreement check are damaged "
            f"({exc}); {retrain}"
        ) from None
    return model


def _check(stored: dict[str, Any] | None) -> DisagreementCheck | None:
    """A stored disagreement check (``None``: none stored)."""
    return None if stored is None else DisagreementCheck.from_dict(stored)
