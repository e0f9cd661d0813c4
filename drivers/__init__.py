"""Device drivers: stereo endoscope (V4L2), force trocar (CAN), projector (HDMI, serial), sim
bench."""

from vbfe.common.errors import DeviceError
from vbfe.drivers.samples import ForceSample, ProjectorEvent, StereoFrame, StreamStats

__all__ = ["DeviceError", "ForceSample", "ProjectorEvent", "StereoFrame", "StreamStats"]
