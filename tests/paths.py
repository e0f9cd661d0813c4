"""Where the tests' shared files are: the repository and its vendored data."""

from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DATA = REPO / "tests" / "data"  # public real inputs, licences in its README.md
