"""Expected failures of force estimation (missing clouds, bad model file, empty dataset)."""

from vbfe.common.errors import VbfeError


class EstimateError(VbfeError):
    """Training or evaluation cannot proceed; the message names the file and what to do."""
