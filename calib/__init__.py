"""Calibration of the stereo endoscope and projector; owns the calibration file format.

The commands of ``vbfe calibrate`` are the functions of :mod:`vbfe.calib.commands`.
"""

from vbfe.calib.board import BoardDetector, BoardSpec, Detection
from vbfe.calib.calibration import Calibration, load_calibration
from vbfe.calib.camera_model import CameraModel
from vbfe.calib.check import CheckResult, check_calibration
from vbfe.calib.export import export_calibration
from vbfe.calib.mono import MonoResult, calibrate_mono
from vbfe.calib.projector import GrayCodeCapture, calibrate_projector, with_projector
from vbfe.calib.stereo import StereoOptions, StereoResult, calibrate_detections, calibrate_stereo
from vbfe.calib.views import ViewSet, load_views, save_views
from vbfe.common.errors import CalibrationError

__all__ = [
    "BoardDetector",
    "BoardSpec",
    "Calibration",
    "CalibrationError",
    "CameraModel",
    "CheckResult",
    "Detection",
    "GrayCodeCapture",
    "MonoResult",
    "StereoOptions",
    "StereoResult",
    "ViewSet",
    "calibrate_detections",
    "calibrate_mono",
    "calibrate_projector",
    "calibrate_stereo",
    "check_calibration",
    "export_calibration",
    "load_calibration",
    "load_views",
    "save_views",
    "with_projector",
]
