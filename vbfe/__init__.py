"""vbfe: vision-based force estimation for soft-tissue interaction (structured light + stereo
endoscope)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("vbfe")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
