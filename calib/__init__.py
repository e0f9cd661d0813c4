"""Calibration of the stereo endoscope and projector; owns the calibration file format."""
