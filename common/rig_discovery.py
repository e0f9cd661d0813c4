"""Which rig file a command uses, found the way python-can finds its configuration.

In order: the ``--config`` option, then the ``$VBFE_RIG`` environment variable, then
``./vbfe-rig.toml``, then ``rig.toml`` in the user config folder (platformdirs, e.g.
``~/.config/vbfe/rig.toml``). The first one named or present wins; a file named by ``--config``
or ``$VBFE_RIG`` must exist. When none is found the simulated bench runs, and
:meth:`RigSource.describe` says so (every command prints it first; sessions store it).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import platformdirs

from vbfe.common.errors import ConfigError

ENV_VAR = "VBFE_RIG"
LOCAL_NAME = "vbfe-rig.toml"
SIMULATED = "simulated bench"


def user_rig_path() -> Path:
    """``rig.toml`` in this user's config folder for vbfe."""
    return platformdirs.user_config_path("vbfe") / "rig.toml"


@dataclass(frozen=True)
class RigSource:
    """Where the rig configuration came from: ``path`` (``None``: no rig file, the built-in
    simulated bench), how it was found (``"--config"``, ``"$VBFE_RIG"``, ``"./vbfe-rig.toml"``,
    ``"user config folder"``) and the places searched, in order."""

    path: Path | None
    found_by: str
    searched: tuple[str, ...]

    def describe(self) -> str:
        """One line: the rig file and how it was found, or that the simulated bench runs."""
        if self.path is None and not self.searched:
            return f"{SIMULATED}: no rig file (the built-in configuration)"
        if self.path is None:
            return f"{SIMULATED}: no rig file (searched {', '.join(self.searched)})"
        return f"rig file {self.path} (from {self.found_by})"


def find_rig_file(
    explicit: str | Path | None = None,
    environ: Mapping[str, str] | None = None,
    cwd: str | Path | None = None,
    named_by: str = "--config",
) -> RigSource:
    """The rig file to use (see the module docstring); ``named_by`` says who named
    ``explicit`` (e.g. the console's Rig tab).

    :raises ConfigError: ``--config`` or ``$VBFE_RIG`` names a file that does not exist.
    """
    environ = os.environ if environ is None else environ
    here = Path.cwd() if cwd is None else Path(cwd)
    if explicit is not None:
        path = Path(explicit)
        if not path.is_file():
            what = "is a folder; give the TOML file" if path.is_dir() else "does not exist"
            raise ConfigError(f"rig config {path} {what}")
        return RigSource(path, named_by, (named_by,))
    named = environ.get(ENV_VAR, "")
    if named:
        path = Path(named)
        if not path.is_file():
            raise ConfigError(
                f"${ENV_VAR} names {path}, which is not a file; correct it or unset {ENV_VAR}"
            )
        return RigSource(path, f"${ENV_VAR}", ("--config", f"${ENV_VAR}"))
    searched = ["--config", f"${ENV_VAR}", f"./{LOCAL_NAME}"]
    local = here / LOCAL_NAME
    if local.is_file():
        return RigSource(local, f"./{LOCAL_NAME}", tuple(searched))
    user = user_rig_path()
    searched.append(str(user))
    if user.is_file():
        return RigSource(user, "user config folder", tuple(searched))
    return RigSource(None, "", tuple(searched))
