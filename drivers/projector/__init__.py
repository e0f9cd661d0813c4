"""Pattern projectors."""

from vbfe.drivers.projector.base import Projector

__all__ = ["Projector"]
