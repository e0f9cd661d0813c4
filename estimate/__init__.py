"""Force estimation from point clouds: PointNet regressor, baselines, training, evaluation."""

from vbfe.estimate.baselines import AffineBaseline, RidgeBaseline, fit_baselines
from vbfe.estimate.dataset import (PreparedSession, SessionSplit, prepare_session,
                                   prepare_sessions, split_by_session, split_by_time)
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.evaluation import EvaluationReport, evaluate
from vbfe.estimate.model_file import ForceModel, load_model
from vbfe.estimate.pointnet import PointNetRegressor, TemporalPointNet, normalize_clouds
from vbfe.estimate.sources import RecordedSession, SessionClouds
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.training import TrainResult, train, use_threads

__all__ = ["AffineBaseline", "EstimateError", "EvaluationReport", "ForceModel",
           "PointNetRegressor", "PreparedSession", "RecordedSession", "RidgeBaseline",
           "SessionClouds", "SessionSplit", "TemporalPointNet", "TrainConfig", "TrainResult",
           "evaluate", "fit_baselines", "load_model", "normalize_clouds", "prepare_session",
           "prepare_sessions", "split_by_session", "split_by_time", "train", "use_threads"]
