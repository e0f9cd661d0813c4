"""The ``[batch]`` table: which executor runs one task per session, and where."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from vbfe.batch.executors import EXECUTORS
from vbfe.common.settings import parse_table


@dataclass(frozen=True)
class BatchSettings:
    """The ``[batch]`` table."""

    # a Literal of a tuple's values: the settings parser reads them; mypy cannot
    executor: Literal[EXECUTORS] = "local"  # type: ignore[valid-type]
    ray_address: str = ""  # "": a local Ray


def batch_settings(
    table: dict[str, Any], executor: str | None = None, ray_address: str | None = None
) -> tuple[str, str | None]:
    """The executor and Ray address: the given ones (command-line options) over the table."""
    settings = parse_table(BatchSettings, table, "batch")
    return executor or settings.executor, ray_address or settings.ray_address or None
