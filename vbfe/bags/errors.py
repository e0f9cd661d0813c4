"""The error of the bag export and import."""

from vbfe.common.errors import VbfeError


class BagError(VbfeError):
    """A session that cannot be exported, or a bag that cannot be imported, as asked."""
