"""One way to turn a rig-config table into settings: check every key and value, then build.

:func:`parse_table` builds a dataclass whose fields are the table's keys; :func:`parse_kwargs`
checks a table meant as keyword arguments of a callable (a device backend, the simulated bench)
against its signature and annotations. Both raise :class:`~vbfe.common.config.ConfigError` with one
line naming the table and the key: an unknown key (with the known ones), a value of the wrong
type, a value outside its range or not among its choices. Ranges come from :func:`setting`.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import operator
import os
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, TypeVar

from vbfe.common.errors import ConfigError, VbfeError

T = TypeVar("T")
_TOML_SCALARS = (bool, int, float, str)


def limits(**bounds: float) -> dict[str, Any]:
    """The metadata giving a dataclass field its range (``gt``/``ge``/``lt``/``le``): for a
    required field, ``dataclasses.field(metadata=limits(ge=1))`` (mypy takes only
    ``dataclasses.field`` for a field without a default)."""
    return {"limits": bounds}


def setting(
    default: Any,
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
) -> Any:
    """A dataclass field with its default and an optional range (``gt``/``ge``/``lt``/``le``)."""
    bounds = {"gt": gt, "ge": ge, "lt": lt, "le": le}
    metadata = limits(**{k: v for k, v in bounds.items() if v is not None})
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


class _Mismatch(Exception):
    """A value does not fit a type."""


def _describe(hint: Any) -> str:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in args if a is not type(None))
    if origin in (list, tuple, Sequence):
        return (
            f"a list of {_describe(args[0]).removeprefix('a ').removeprefix('an ')}s"
            if args
            else "a list"
        )
    names = {
        bool: "true or false",
        int: "an integer",
        float: "a number",
        str: "a string",
        Path: "a path (string)",
    }
    return names.get(hint, getattr(hint, "__name__", str(hint)))


def _coerce(value: Any, hint: Any) -> Any:
    """``value`` as the type ``hint`` names (int → float, list → tuple); else _Mismatch."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any or hint is inspect.Parameter.empty:
        return value
    if origin is Literal:
        if value in args and type(value) in {type(a) for a in args}:
            return value
        raise _Mismatch
    if origin in (typing.Union, types.UnionType):
        for arm in args:
            if arm is type(None):
                continue
            try:
                return _coerce(value, arm)
            except _Mismatch:
                pass
        raise _Mismatch
    if origin in (list, tuple, Sequence) or hint in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise _Mismatch
        item = args[0] if args else Any
        items = [_coerce(v, item) for v in value]
        return tuple(items) if origin is tuple or hint is tuple else items
    if origin is dict or hint is dict:
        if not isinstance(value, dict):
            raise _Mismatch
        return value
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise _Mismatch
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise _Mismatch
    if hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise _Mismatch
    if hint is str or hint in (Path, os.PathLike):
        if isinstance(value, str):
            return value
        raise _Mismatch
    raise _Mismatch


def _toml_able(hint: Any) -> bool:
    """Whether a TOML value can be of this type (callables and objects cannot)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any or hint is inspect.Parameter.empty or origin is Literal:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(_toml_able(a) for a in args if a is not type(None))
    if origin in (list, tuple, Sequence, dict):
        return all(_toml_able(a) for a in args if a is not Ellipsis)
    return hint in (*_TOML_SCALARS, Path, os.PathLike, list, tuple, dict)


def _check(table: str, key: str, value: Any, hint: Any, limits: Mapping[str, float]) -> Any:
    try:
        value = _coerce(value, hint)
    except _Mismatch:
        raise ConfigError(f"[{table}] {key} = {value!r} is not {_describe(hint)}") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"[{table}] {key} = {value!r} is not a finite number")
    for name, bound in limits.items():
        ok = {"gt": operator.gt, "ge": operator.ge, "lt": operator.lt, "le": operator.le}[name]
        if not ok(value, bound):
            sign = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}[name]
            raise ConfigError(
                f"[{table}] {key} = {value!r} is out of range: it must be {sign} {bound:g}"
            )
    return value


def _unknown(table: str, key: str, known: Sequence[str], where: str = "") -> ConfigError:
    return ConfigError(
        f"unknown key {key!r} in [{table}]{where}; known: {', '.join(sorted(known)) or 'none'}"
    )


def parse_table(cls: type[T], table: Mapping[str, Any], name: str) -> T:
    """An instance of dataclass ``cls`` from config table ``[name]``: every key must be a field,
    every value of the field's type (and range); absent keys keep the field's default."""
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    hints = typing.get_type_hints(cls)
    values = {}
    for key, value in table.items():
        if key not in fields:
            raise _unknown(name, key, list(fields))
        values[key] = _check(name, key, value, hints[key], fields[key].metadata.get("limits", {}))
    return cls(**values)


def config_parameters(target: Callable[..., Any]) -> dict[str, Any]:
    """The keyword arguments of ``target`` a config table may set, with their annotations
    (parameters typed as callables or objects, and ``*args``/``**kwargs``, are left out)."""
    try:
        hints = typing.get_type_hints(target.__init__ if inspect.isclass(target) else target)
    except (NameError, TypeError):
        hints = {}
    out = {}
    for param in inspect.signature(target).parameters.values():
        if param.kind in (param.VAR_POSITIONAL, param.VAR_KEYWORD) or param.name == "self":
            continue
        hint = hints.get(param.name, param.annotation)
        if isinstance(hint, str):
            hint = Any
        if _toml_able(hint):
            out[param.name] = hint
    return out


def parse_kwargs(
    target: Callable[..., Any],
    table: Mapping[str, Any],
    name: str,
    where: str = "",
    skip: Sequence[str] = (),
) -> dict[str, Any]:
    """Table ``[name]`` checked as keyword arguments of ``target`` (its signature and type
    annotations); ``where`` adds context to messages, e.g. ``" (backend can)"``."""
    known = {k: v for k, v in config_parameters(target).items() if k not in skip}
    out = {}
    for key, value in table.items():
        if key not in known:
            raise _unknown(name, key, list(known), where)
        out[key] = _check(name, key, value, known[key], {})
    return out


def parse_conditions(pairs: list[str]) -> dict[str, object]:
    """KEY=VALUE pairs as a conditions table (numbers where they parse)."""
    out: dict[str, object] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise VbfeError(f"--condition {pair!r} is not KEY=VALUE")
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = value
    return out
