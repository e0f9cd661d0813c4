"""Expected failures of reconstruction."""

from vbfe.errors import VbfeError


class ReconError(VbfeError):
    """Reconstruction cannot run: missing or mismatched calibration, unreadable session/sidecar."""
