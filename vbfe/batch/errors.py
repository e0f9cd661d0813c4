"""The error of the batch layer."""

from vbfe.errors import VbfeError


class BatchError(VbfeError):
    """A dataset folder, manifest or executor that cannot be used as given."""
