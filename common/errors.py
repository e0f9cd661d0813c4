"""Root of the expected-failure exceptions; each package derives its own type from it."""


class VbfeError(Exception):
    """An expected failure (device gone, bad file, bad calibration) with a message for the operator."""
