"""Force estimation from point clouds: PointNet, image models, baselines, selection, evaluation."""

from vbfe.common.errors import EstimateError
from vbfe.estimate.evaluation import EvaluationReport, evaluate
from vbfe.estimate.inference import FramePredictor
from vbfe.estimate.model_file import ForceModel, load_model
from vbfe.estimate.sources import RecordedSession, SessionClouds
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.training import TrainResult, train, use_threads

__all__ = [
    "EstimateError",
    "EvaluationReport",
    "ForceModel",
    "FramePredictor",
    "RecordedSession",
    "SessionClouds",
    "TrainConfig",
    "TrainResult",
    "evaluate",
    "load_model",
    "train",
    "use_threads",
]
