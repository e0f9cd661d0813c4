"""Settings dataclasses filled from the rig config's ``[calib]`` table."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

T = TypeVar("T")


def from_table(cls: type[T], table: dict[str, Any], keys: dict[str, str] | None = None,
               scales: dict[str, float] | None = None) -> T:
    """An instance of dataclass ``cls`` whose fields come from ``table`` where present.

    ``keys`` maps a field to its config key when the names differ; ``scales`` converts config
    units to the field's (e.g. mm → m: ``1e-3``). Values take the type of the field's default.
    """
    keys, scales = keys or {}, scales or {}
    values = {}
    for f in dataclasses.fields(cls):
        key = keys.get(f.name, f.name)
        if key in table:
            value = table[key] * scales[f.name] if f.name in scales else table[key]
            values[f.name] = type(f.default)(value)
    return cls(**values)
