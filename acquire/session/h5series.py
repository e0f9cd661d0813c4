"""The one kind of dataset a session appends to: resizable, chunked, Fletcher-32 checksummed."""

from __future__ import annotations

from typing import Any

import h5py
import numpy as np

TIME_CHUNK = 4096


def series(group: h5py.Group, name: str, dtype: Any, width: int | None = None,
           chunk: int = TIME_CHUNK, **kwargs: Any) -> h5py.Dataset:
    """An empty ``(0,)`` (or ``(0, width)``) dataset that grows along axis 0."""
    shape, maxshape, chunks = (0,), (None,), (chunk,)
    if width is not None:
        shape, maxshape, chunks = (0, width), (None, width), (chunk, width)
    return group.create_dataset(name, shape=shape, maxshape=maxshape, chunks=chunks, dtype=dtype,
                                fletcher32=True, **kwargs)


def append(ds: h5py.Dataset, values: np.ndarray) -> None:
    """Append rows to a series."""
    n = ds.shape[0]
    ds.resize(n + len(values), axis=0)
    ds[n:] = values
