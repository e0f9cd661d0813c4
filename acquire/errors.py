"""Expected failures of the session recorder and reader."""

from vbfe.common.errors import VbfeError


class SessionError(VbfeError):
    """A session file is missing, unwritable, truncated, corrupt or not a vbfe session."""
