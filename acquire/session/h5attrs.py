"""Reading HDF5 attributes and scalar datasets back as plain Python values."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np


def plain_attrs(attrs: Mapping[str, Any]) -> dict[str, Any]:
    """An ``h5py`` attribute set as a dict, NumPy scalars turned into Python ones."""
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in attrs.items()}


def text(value: Any) -> str:
    """A stored string (h5py gives ``bytes`` or ``str``) as ``str``."""
    return value.decode() if isinstance(value, bytes) else str(value)
