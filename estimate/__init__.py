"""Force estimation from point clouds: PointNet, image models, baselines, selection, evaluation.

The names below load their module on first use, so that reading a ``[train]`` table or a
split (:mod:`vbfe.estimate.train_config`, :mod:`vbfe.estimate.splits`) does not import torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from vbfe.common.errors import EstimateError

if TYPE_CHECKING:
    from vbfe.estimate.evaluation import EvaluationReport as EvaluationReport
    from vbfe.estimate.evaluation import evaluate as evaluate
    from vbfe.estimate.inference import FramePredictor as FramePredictor
    from vbfe.estimate.live_predictor import LivePredictor as LivePredictor
    from vbfe.estimate.model_file import ForceModel as ForceModel
    from vbfe.estimate.model_file import load_model as load_model
    from vbfe.estimate.sources import (
        RecordedSession as RecordedSession,
    )
    from vbfe.estimate.sources import (
        SessionClouds as SessionClouds,
    )
    from vbfe.estimate.train_config import TrainConfig as TrainConfig
    from vbfe.estimate.training import (
        TrainResult as TrainResult,
    )
    from vbfe.estimate.training import (
        train as train,
    )
    from vbfe.estimate.training import (
        use_threads as use_threads,
    )

_MODULES = {
    "EvaluationReport": "evaluation",
    "evaluate": "evaluation",
    "FramePredictor": "inference",
    "LivePredictor": "live_predictor",
    "ForceModel": "model_file",
    "load_model": "model_file",
    "RecordedSession": "sources",
    "SessionClouds": "sources",
    "TrainConfig": "train_config",
    "TrainResult": "training",
    "train": "training",
    "use_threads": "training",
}

__all__ = ["EstimateError", *_MODULES]


def __getattr__(name: str) -> Any:
    """The public name ``name``, imported from its module on first use."""
    if name not in _MODULES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_MODULES[name]}"), name)
    globals()[name] = value
    return value
