"""Expected calibration failures."""

from vbfe.common.errors import VbfeError


class CalibrationError(VbfeError):
    """Views or calibration files that cannot give (or are not) a usable calibration."""
