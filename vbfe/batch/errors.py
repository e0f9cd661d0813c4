"""The error of the batch layer."""

from vbfe.common.errors import VbfeError


class BatchError(VbfeError):
    """A dataset folder, manifest or executor that cannot be used as given."""
