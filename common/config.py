"""Rig configuration: one TOML file per rig, one table per component.

Each package parses its own table (``[camera]``, ``[trocar]``, ``[projector]``, ``[record]``,
``[sgbm]``, ``[calib]``, ``[train]``, ``[bench]``) into its own settings; this module only
loads the file and merges it over the defaults, which run the simulated bench.
"""

from __future__ import annotations

import copy
import logging
import sys
from importlib import resources
from pathlib import Path
from typing import Any

from vbfe.common.errors import ConfigError, VbfeError

log = logging.getLogger(__name__)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised only on 3.10
    import tomli as tomllib


def default_config() -> dict[str, dict[str, Any]]:
    """The built-in configuration: every device on the simulated bench."""
    text = resources.files("vbfe").joinpath("default_rig.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def merge_tables(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """``override`` merged over a copy of ``base``, table by table."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_tables(out[key], value)
        else:
            out[key] = value
    return out


def read_toml(path: str | Path, what: str, error: type[VbfeError] = ConfigError) -> dict[str, Any]:
    """Parse a TOML file; ``error`` names ``what`` and the file when it is missing or invalid."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise error(f"{what} {path} does not exist") from None
    except IsADirectoryError:
        raise error(f"{what} {path} is a folder; give the TOML file") from None
    except OSError as exc:
        raise error(f"{what} {path} cannot be read: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise error(f"{what} {path} is not a text (TOML) file") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {path} is not valid TOML: {exc}") from None


def over_defaults(user: dict[str, Any], where: str = "rig config") -> dict[str, dict[str, Any]]:
    """A rig file's tables merged over the defaults (an unknown table is a ConfigError)."""
    config = default_config()
    unknown = set(user) - set(config)
    if unknown:
        raise ConfigError(
            f"{where} has unknown table(s) {sorted(unknown)}; known: {sorted(config)}"
        )
    log.info("%s read: tables %s", where, ", ".join(sorted(user)))
    return merge_tables(config, user)
