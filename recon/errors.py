"""Expected failures of reconstruction."""

from vbfe.common.errors import VbfeError


class ReconError(VbfeError):
    """Reconstruction cannot run: missing or mismatched calibration, unreadable session/sidecar."""
