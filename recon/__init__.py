"""Structured-light stereo reconstruction: pattern, colour correction, matching, point clouds."""

from vbfe.common.errors import ReconError
from vbfe.drivers.projector.pattern import make_pattern, save_pattern
from vbfe.recon.clouds import CloudReader, export_ply, sidecar_path, write_ply
from vbfe.recon.color import ColorModel, estimate_color_model
from vbfe.recon.matching import SgbmParams
from vbfe.recon.session_recon import reconstruct_session
from vbfe.recon.triangulate import FrameCloud, Reconstructor

__all__ = [
    "CloudReader",
    "ColorModel",
    "FrameCloud",
    "ReconError",
    "Reconstructor",
    "SgbmParams",
    "estimate_color_model",
    "export_ply",
    "make_pattern",
    "reconstruct_session",
    "save_pattern",
    "sidecar_path",
    "write_ply",
]
