"""Pieces shared by the subcommands: the --config option and progress bars."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from typing import Any

from tqdm import tqdm

from vbfe.common.errors import ConfigError
from vbfe.estimate.stage_times import STATUS_SEPARATOR
from vbfe.rig_config import RigConfig, load_rig, settle


def add_config_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--config rig.toml``; without it the rig file is found as
    :mod:`vbfe.common.rig_discovery` says (else the simulated bench runs)."""
    parser.add_argument(
        "--config",
        metavar="RIG.toml",
        default=None,
        help="rig file (default: $VBFE_RIG, then ./vbfe-rig.toml, then rig.toml in the user "
        "config folder; none: the simulated bench)",
    )


def add_settle_option(parser: argparse.ArgumentParser, what: str) -> None:
    """Add ``--settle``: keep ``what`` in the rig file for the next commands."""
    parser.add_argument(
        "--settle",
        action="store_true",
        help=f"keep {what} in the rig file, so the next commands (and the next day) start "
        "there (comments kept, the previous file backed up)",
    )


def check_settle(args: argparse.Namespace) -> None:
    """Before any work: ``--settle`` needs a rig file to write into.

    :raises ConfigError: there is none (the simulated bench's defaults).
    """
    if getattr(args, "settle", False) and rig_from(args).source.path is None:
        raise ConfigError(
            "--settle: no rig file to keep the result in; write one with `vbfe rig init` "
            "or name it with --config"
        )


def settle_values(args: argparse.Namespace, changes: dict[str, dict[str, Any]]) -> None:
    """With ``--settle``: write ``changes`` (table -> key -> value) into the rig file and
    print what changed (tuples as lists; ``None`` values left out)."""
    if not getattr(args, "settle", False):
        return
    plain = {
        table: {
            k: list(v) if isinstance(v, tuple) else v for k, v in values.items() if v is not None
        }
        for table, values in changes.items()
    }
    written = settle(rig_from(args), plain)
    if written is not None:
        print(written.text())


def positive(kind: type = float, zero: bool = False) -> Callable[[str], Any]:
    """An argparse type: a finite number of type ``kind`` above 0 (from 0 with ``zero``)."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not {'an integer' if kind is int else 'a number'}"
            ) from None
        if not math.isfinite(value) or value < 0 or (value == 0 and not zero):
            raise argparse.ArgumentTypeError(
                f"must be {'0 or more' if zero else 'positive'}, got {text}"
            )
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


def rig_from(args: argparse.Namespace) -> RigConfig:
    """The rig configuration the user chose, parsed once per command (the entry point loads
    it before the command runs and prints its banner)."""
    rig = getattr(args, "rig", None)
    if rig is None:
        rig = args.rig = load_rig(getattr(args, "config", None))
    return rig


def progress(total: int | None = None, desc: str = "", unit: str = "it") -> tqdm:
    """A progress bar on stderr; quiet when stderr is not a terminal and CI is set."""
    return tqdm(
        total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True, mininterval=0.5
    )


class LazyProgress:
    """A progress bar opened at its first update, so a command that fails before doing any
    work prints only its error line (context manager)."""

    def __init__(self, desc: str, unit: str) -> None:
        self.desc, self.unit = desc, unit
        self._bar: tqdm | None = None

    def __call__(self, done: int, total: int | None = None) -> None:
        if self._bar is None:
            self._bar = progress(total=total, desc=self.desc, unit=self.unit)
        self._bar.update(done - self._bar.n)

    def __enter__(self) -> LazyProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.close()


STAGE_UNITS = {"sessions": "session", "epochs": "epoch", "predict": "session"}


class StageProgress:
    """One progress bar per stage of a ``(stage, done, total)`` progress callback; a stage
    ``"name · status"`` (``STATUS_SEPARATOR``) keeps the bar of ``name`` and shows the status."""

    def __init__(self) -> None:
        self._stage: str | None = None
        self._bar: tqdm | None = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        name = stage.split(STATUS_SEPARATOR)[0]
        if name != self._stage:
            self.close()
            self._stage = name
            unit = STAGE_UNITS.get(name.split()[-1], "it")
            self._bar = progress(total=total, desc=stage, unit=unit)
        assert self._bar is not None
        self._bar.set_description(stage, refresh=False)
        self._bar.update(done - self._bar.n)

    def close(self) -> None:
        """Close the current bar."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
