"""The error of live estimation."""

from vbfe.common.errors import VbfeError


class LiveError(VbfeError):
    """Live estimation cannot start or went wrong (device gone, bad model or calibration)."""
