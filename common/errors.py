"""The expected failures of vbfe: :class:`VbfeError` and the one type each package raises.

An expected failure (device gone, bad file, bad calibration) carries a one-line message for the
operator naming what is wrong and what to do; ``vbfe`` prints it and exits with status 2
(:data:`EXIT_BAD_INPUT`). Anything else is a bug and keeps its traceback.
"""

EXIT_BAD_INPUT = 2  # a VbfeError, an unreadable/unwritable file, not enough memory
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT)
EXIT_TERMINATED = 143  # SIGTERM (128 + SIGTERM)


class VbfeError(Exception):
    """An expected failure (device gone, bad file, bad calibration) with a message for the
    operator."""


class ConfigError(VbfeError):
    """The rig configuration file is missing, unreadable or has a wrong value."""


class OutputError(VbfeError):
    """An output path would overwrite data, or cannot be written."""


class DeviceError(VbfeError):
    """A device is missing, vanished, timed out or answered nonsense; the message names it."""


class SessionError(VbfeError):
    """A session file is missing, unwritable, truncated, corrupt or not a vbfe session."""


class CalibrationError(VbfeError):
    """Views or calibration files that cannot give (or are not) a usable calibration."""


class ReconError(VbfeError):
    """Reconstruction cannot run: missing or mismatched calibration, unreadable session/sidecar."""


class EstimateError(VbfeError):
    """Training or evaluation cannot proceed; the message names the file and what to do."""


class TruthError(VbfeError):
    """Ground truth was asked of something that has none (e.g. a session from a real rig)."""


class BatchError(VbfeError):
    """A dataset folder, manifest or executor that cannot be used as given."""


class BagError(VbfeError):
    """A session that cannot be exported, or a bag that cannot be imported, as asked."""


class LiveError(VbfeError):
    """Live estimation cannot start or went wrong (device gone, bad model or calibration)."""
