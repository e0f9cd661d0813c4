"""Structured-light stereo reconstruction: pattern, colour correction, matching, point clouds."""
