"""Checks on the destination of a recording: writable directory, enough free space."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from vbfe.common.errors import SessionError


def free_bytes(directory: str | Path) -> int:
    """Free bytes available on the file system holding ``directory``."""
    return shutil.disk_usage(directory).free


def check_destination(path: str | Path, min_free_bytes: int, overwrite: bool = False) -> Path:
    """Fail at once, naming the path, when a session cannot be written there."""
    path = Path(path).absolute()
    directory = path.parent
    if path.exists() and not overwrite:
        raise SessionError(f"{path} already exists; choose a new file name or remove it first")
    if not directory.is_dir():
        raise SessionError(f"cannot record to {path}: directory {directory} does not exist")
    try:
        with tempfile.NamedTemporaryFile(dir=directory, prefix=".vbfe-write-test-"):
            pass
    except OSError as exc:
        raise SessionError(
            f"cannot record to {path}: directory {directory} is not writable "
            f"({exc.strerror}); choose another directory"
        ) from None
    free = free_bytes(directory)
    if free < min_free_bytes:
        raise SessionError(
            f"cannot record to {path}: only {free / 1e9:.2f} GB free on "
            f"{directory}, need at least {min_free_bytes / 1e9:.2f} GB; free space "
            "or record elsewhere"
        )
    if not os.access(directory, os.W_OK):
        raise SessionError(f"cannot record to {path}: directory {directory} is not writable")
    return path
