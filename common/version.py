"""The installed vbfe's version (stored in every file vbfe writes)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("vbfe")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
