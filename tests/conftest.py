"""Test-wide settings: headless Qt and matplotlib."""

import os
import tempfile

import vbfe  # noqa: F401  (first: its thread-pool settings must precede numpy and torch)

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")
# commands find no rig file of the machine's: each test names its own (or runs the bench)
os.environ.pop("VBFE_RIG", None)
os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="vbfe-test-config-")
