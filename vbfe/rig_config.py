"""The rig configuration, parsed and checked once at the edge into typed sections.

:func:`load_rig` finds the rig file (:mod:`vbfe.common.rig_discovery`), merges it over the
built-in defaults (vbfe/default_rig.toml, the simulated bench) and parses every table into its
package's settings dataclass, so a typo anywhere (unknown key, wrong type, value out of range)
is one :class:`~vbfe.common.errors.ConfigError` naming the key and the file before any command
starts. Library code takes the typed sections (``rig.record``, ``rig.calib``, ...); the device
tables (``[camera]``, ``[trocar]``, ``[projector]``, ``[bench]``, ``[streams]``) stay in
``rig.tables`` for :func:`vbfe.drivers.registry.open_rig`, which checks them against their
backends. :attr:`RigConfig.origins` says where each value came from (``vbfe rig show``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vbfe.acquire.recording.settings import RecordSettings, record_settings
from vbfe.batch.settings import BatchSettings
from vbfe.calib.options import CalibSettings, calib_settings
from vbfe.common.config import default_config, merge_tables, over_defaults, read_toml
from vbfe.common.errors import ConfigError
from vbfe.common.rig_discovery import RigSource, find_rig_file
from vbfe.common.rig_writeback import WriteBack, write_back
from vbfe.common.settings import parse_kwargs, parse_table
from vbfe.estimate import TrainConfig
from vbfe.live.settings import LiveSettings, live_settings
from vbfe.recon import SgbmParams
from vbfe.recon.quality import ReconSettings

DEVICE_TABLES = ("camera", "trocar", "projector", "bench", "streams")
DEFAULT_ORIGIN = "default"


@dataclass(frozen=True)
class RigConfig:
    """Every table of the rig configuration, checked; see the module docstring."""

    source: RigSource
    tables: dict[str, dict[str, Any]]  # the merged tables (device tables for open_rig)
    origins: dict[tuple[str, str], str]  # (table, key) -> "default" or where it was set
    record: RecordSettings
    calib: CalibSettings
    sgbm: SgbmParams
    recon: ReconSettings
    live: LiveSettings
    train: TrainConfig
    batch: BatchSettings

    @property
    def simulated(self) -> bool:
        """Whether every device of the rig is the simulated bench's."""
        return all(
            self.tables.get(f, {}).get("backend", "sim") == "sim"
            for f in ("camera", "trocar", "projector")
        )

    def set_by_file(self, table: str, key: str) -> bool:
        """Whether the rig file sets ``[table] key`` (not the built-in default)."""
        return self.origins.get((table, key), DEFAULT_ORIGIN) != DEFAULT_ORIGIN

    def banner(self) -> str:
        """The line every command prints first: the rig file, or that the simulator runs."""
        if self.source.path is not None and self.simulated:
            return f"{self.source.describe()}: simulated bench"
        return self.source.describe()

    def updated(self, changes: dict[str, dict[str, Any]], where: str = "changed") -> RigConfig:
        """This configuration with ``changes`` (table -> key -> value) merged in and every
        table checked again (a bad value: ConfigError naming the key); the changed keys' origin
        is ``where``. Nothing is written (:func:`settle` writes a rig file)."""
        tables = merge_tables(self.tables, changes)
        origins = {**self.origins, **{(t, k): where for t, v in changes.items() for k in v}}
        return RigConfig(self.source, tables, origins, **check_tables(tables, changes))


def check_tables(tables: dict[str, dict[str, Any]], user: dict[str, Any] | None = None) -> Any:
    """Parse every non-device table of ``tables`` (the merged configuration); device tables
    that ``user`` (the file's own tables; default: all) sets are checked against their
    backends. Returns the typed sections as a dict; raises ConfigError naming the key."""
    from vbfe.drivers.registry import FAMILIES, device_options

    unknown = set(tables) - set(default_config())
    if unknown:
        raise ConfigError(f"unknown table(s) {sorted(unknown)}; known: {sorted(default_config())}")
    sections = {
        "record": record_settings(tables),
        "calib": calib_settings(tables.get("calib", {})),
        "sgbm": SgbmParams.from_config(tables.get("sgbm", {})),
        "recon": ReconSettings.from_config(tables.get("recon", {})),
        "live": live_settings(tables.get("live", {})),
        "train": TrainConfig.from_table(tables.get("train", {})),
        "batch": parse_table(BatchSettings, tables.get("batch", {}), "batch"),
    }
    given = tables if user is None else user
    for family in FAMILIES:
        if family in given:
            device_options(family, tables.get(family, {}))
    if "bench" in given:
        from vbfe.drivers.sim.bench import SimBench

        parse_kwargs(SimBench, tables.get("bench", {}), "bench", skip=("rig",))
    if given.get("streams"):
        from vbfe.drivers.streams.opening import streams_from_config

        streams_from_config(tables)
    return sections


def builtin_rig(changes: dict[str, dict[str, Any]] | None = None) -> RigConfig:
    """The built-in configuration (the simulated bench), no rig file searched, with
    ``changes`` (table -> key -> value) merged in; for code that builds its rig in code
    (the demo, tests, benchmarks). A bad value is a ConfigError naming the key."""
    source = RigSource(None, "", ())
    tables = default_config()
    rig = RigConfig(source, tables, _origins({}, ""), **check_tables(tables, {}))
    return rig.updated(changes, "built in") if changes else rig


def _origins(user: dict[str, Any], where: str) -> dict[tuple[str, str], str]:
    defaults = default_config()
    out = {(t, k): DEFAULT_ORIGIN for t, table in defaults.items() for k in table}
    for table, values in user.items():
        for key in values:
            out[(table, key)] = where
    return out


def load_rig(explicit: str | Path | None = None, named_by: str = "--config") -> RigConfig:
    """The rig configuration a command uses: ``--config`` (``explicit``; ``named_by`` says
    who named it), ``$VBFE_RIG``, ``./vbfe-rig.toml``, the user config folder, else the
    simulated bench; every table checked.

    :raises ConfigError: the file is missing, not TOML, or has an unknown key or a bad value
        (the message names the key and the file).
    """
    source = find_rig_file(explicit, named_by=named_by)
    user: dict[str, Any] = {}
    if source.path is not None:
        user = read_toml(source.path, "rig config")
    try:
        tables = over_defaults(user, "the file")
        sections = check_tables(tables, user)
    except ConfigError as exc:
        if source.path is None:
            raise
        raise ConfigError(
            f"rig config {source.path} (from {source.found_by}): {exc}; correct that key "
            f"(vbfe/default_rig.toml lists every key with its meaning)"
        ) from None
    where = "" if source.path is None else f"{source.path} ({source.found_by})"
    return RigConfig(source, tables, _origins(user, where), **sections)


def check_file(user: dict[str, Any]) -> None:
    """Check a rig file's own tables as :func:`load_rig` does (the write-back's ``check``)."""
    check_tables(over_defaults(user, "the file"), user)


def settle(rig: RigConfig, changes: dict[str, dict[str, Any]]) -> WriteBack | None:
    """Write ``changes`` (table -> key -> value) into the rig file ``rig`` came from (comments
    kept, dated backup: :func:`vbfe.common.rig_writeback.write_back`), checked first; ``None``
    when there is no rig file (the simulated bench's defaults are not a file to change)."""
    if rig.source.path is None:
        return None
    try:
        return write_back(rig.source.path, changes, check=check_file)
    except ConfigError as exc:
        raise ConfigError(f"rig file {rig.source.path} not changed: {exc}") from None


def shown(rig: RigConfig) -> str:
    """The effective settings as TOML, each value with where it came from (``vbfe rig show``)."""
    import tomlkit

    lines: list[str] = []
    for table, values in rig.tables.items():
        lines.append(f"[{table}]" if not lines else f"\n[{table}]")
        if not isinstance(values, dict):
            continue
        rows = []
        for key, value in values.items():
            if isinstance(value, dict):  # [streams.NAME] and camera controls: inline
                inline = tomlkit.inline_table()
                inline.update(value)
                text = inline.as_string()
            else:
                text = tomlkit.item(value).as_string()
            rows.append((f"{key} = {text}", rig.origins.get((table, key), DEFAULT_ORIGIN)))
        width = max((len(r) for r, _ in rows), default=0)
        lines += [f"{row:<{width}}  # {origin}" for row, origin in rows]
    return "\n".join(lines)
