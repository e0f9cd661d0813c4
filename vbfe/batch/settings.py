"""The ``[batch]`` table: which executor runs one task per session, and where."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from vbfe.batch.executors import EXECUTORS


@dataclass(frozen=True)
class BatchSettings:
    """The ``[batch]`` table."""

    # a Literal of a tuple's values: the settings parser reads them; mypy cannot
    executor: Literal[EXECUTORS] = "local"  # type: ignore[valid-type]
    ray_address: str = ""  # "": a local Ray
