"""Write what the operator settled back into the rig file, so the next day starts there.

API (for the CLI and the console window)::

    from vbfe.common.rig_writeback import write_back

    done = write_back("rig.toml", {"record": {"frame_time_correction_s": 0.037}})
    done.backup   # Path of the previous file (rig.toml.20261206-041502.bak), None if it was new
    done.changes  # [("record", "frame_time_correction_s", 0.0, 0.037)]: (table, key, was, now)
    print(done.text())  # one line per change, then where the backup is

From the app (CLI, window), ``vbfe.rig_config.settle(rig, changes)`` does the same into the
file a loaded :class:`~vbfe.rig_config.RigConfig` came from, checking every table as the commands
do (``check=vbfe.rig_config.check_file``); it returns ``None`` when there is no rig file.

``changes`` maps table -> key -> value (TOML scalars, lists, :class:`~pathlib.Path` written as
a string). Keys and tables absent from the file are added; every other line, comment and blank
line is kept as it was (tomlkit). The new text is checked before anything is written: it must be
TOML and pass ``check`` when given, else :class:`~vbfe.common.errors.ConfigError` and the file
is untouched. The old file is copied to a dated backup next to it, then the new one is renamed over
it (atomic). A file that would not change is not written and gets no backup. The file need not
exist (it is created, no backup). What to settle where: the board in ``[calib]`` (``target``,
``inner_corners``/``squares_x``/``squares_y``, ``square_mm``, ``marker_mm``, ``dictionary``),
the stereo calibration in ``[calib] calibration``, the sync correction in ``[record]
frame_time_correction_s``, the model in ``[live] model``.
"""

from __future__ import annotations

import datetime as dt
import logging
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomlkit
from tomlkit.exceptions import TOMLKitError

from vbfe.common.errors import ConfigError
from vbfe.common.files import write_bytes_atomic

log = logging.getLogger(__name__)

Change = tuple[str, str, Any, Any]  # table, key, previous value (None: absent), new value


@dataclass(frozen=True)
class WriteBack:
    """What :func:`write_back` did to the rig file."""

    path: Path
    backup: Path | None  # the previous file; None when there was none or nothing changed
    changes: list[Change] = field(default_factory=list)

    def text(self) -> str:
        """One line per changed value, then the backup (or that nothing changed)."""
        if not self.changes:
            return f"rig file {self.path}: already up to date"
        lines = [
            f"rig file {self.path}: [{t}] {k} = {_shown(new)}"
            + (f" (was {_shown(old)})" if old is not None else " (added)")
            for t, k, old, new in self.changes
        ]
        lines.append(f"previous file kept as {self.backup}" if self.backup else "new rig file")
        return "\n".join(lines)


def _shown(value: Any) -> str:
    return tomlkit.item(value).as_string()


def _plain(value: Any, where: str) -> Any:
    """``value`` as a TOML-able Python value (paths as strings, tuples and arrays as lists)."""
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (bool, str)):
        return value
    if hasattr(value, "item") and not isinstance(value, (list, tuple)):  # numpy scalar
        value = value.item()
    if isinstance(value, (int, float)):
        return value
    if hasattr(value, "tolist"):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v, where) for v in value]
    raise ConfigError(f"{where} = {value!r} cannot be written to a rig file (not a TOML value)")


def backup_path(path: Path, now: dt.datetime | None = None) -> Path:
    """A dated name beside ``path`` for its previous version that no file has yet."""
    stamp = (now or dt.datetime.now()).strftime("%Y%m%d-%H%M%S")
    candidate = path.with_name(f"{path.name}.{stamp}.bak")
    n = 1
    while candidate.exists():
        candidate = path.with_name(f"{path.name}.{stamp}-{n}.bak")
        n += 1
    return candidate


def write_back(
    path: str | Path,
    changes: Mapping[str, Mapping[str, Any]],
    *,
    check: Callable[[dict[str, Any]], object] | None = None,
    now: dt.datetime | None = None,
) -> WriteBack:
    """Set ``changes`` (table -> key -> value) in the rig file at ``path``, keeping its
    comments and a dated backup of the previous file (see the module docstring).

    :raises ConfigError: the file is not TOML, a value is not a TOML value, or ``check``
        refuses the result (nothing is written then).
    """
    path = Path(path)
    try:
        old_text = path.read_text(encoding="utf-8") if path.exists() else ""
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"rig file {path} cannot be read: {exc}") from None
    try:
        doc = tomlkit.parse(old_text)
    except TOMLKitError as exc:
        raise ConfigError(
            f"rig file {path} is not valid TOML ({exc}); fix it before settling values"
        ) from None
    done: list[Change] = []
    for table, values in changes.items():
        if table not in doc:
            doc[table] = tomlkit.table()
        target = doc[table]
        if not isinstance(target, Mapping):
            raise ConfigError(f"rig file {path}: {table} is not a table; make it [{table}]")
        for key, value in values.items():
            new = _plain(value, f"[{table}] {key}")
            item: Any = target.get(key)
            old = item.unwrap() if isinstance(item, tomlkit.items.Item) else item
            if old == new and type(old) is type(new):
                continue
            target[key] = new  # type: ignore[index]
            done.append((table, key, old, new))
    if not done:
        return WriteBack(path, None, [])
    new_text = tomlkit.dumps(doc)
    if check is not None:
        check(tomlkit.parse(new_text).unwrap())
    backup = None
    if path.exists():
        backup = backup_path(path, now)
        shutil.copy2(path, backup)
    write_bytes_atomic(path, new_text)
    log.info("rig file %s: %d value(s) settled, backup %s", path, len(done), backup)
    return WriteBack(path, backup, done)
