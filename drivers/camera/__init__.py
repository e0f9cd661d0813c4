"""Stereo endoscope cameras."""

from vbfe.drivers.camera.base import StereoCamera

__all__ = ["StereoCamera"]
