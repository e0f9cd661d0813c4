"""vbfe: vision-based force estimation for soft-tissue interaction (structured light + stereo
endoscope)."""

from vbfe.common.version import __version__

__all__ = ["__version__"]
