"""Expected device failures."""

from vbfe.common.errors import VbfeError


class DeviceError(VbfeError):
    """A device is missing, vanished, timed out or answered nonsense; the message names it."""
