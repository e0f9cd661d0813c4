"""Rows appended to a deflate-compressed HDF5 dataset, each full chunk compressed on a thread.

HDF5's deflate filter compresses a chunk inside the write call, on the writing thread: the
reconstruction's writer spent 43 ms per full-demo frame there (points and colours) in the one
process that gathers every worker's frames, and the reconstruction waited on it. Here rows are
gathered until a chunk is full, zlib (which releases the GIL) compresses it on a thread while
the writer goes on, and the bytes are stored with HDF5's direct chunk write: the dataset keeps
its plain deflate filter, so h5py, h5dump, MATLAB and HDFView decode it as they did.
"""

from __future__ import annotations

import zlib
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor

import h5py
import numpy as np

LEVEL = 1  # HDF5's ``compression_opts`` of the datasets written here
MAX_PENDING = 8  # chunks compressing at once per dataset before the writer waits


def _deflate(chunk: np.ndarray) -> bytes:
    """A chunk as HDF5's deflate filter stores it (a zlib stream of its bytes)."""
    return zlib.compress(chunk.data, LEVEL)


class DeflatedRows:
    """Appends rows to ``ds`` (created resizable along its first axis, chunked whole rows,
    ``compression="gzip"`` at :data:`LEVEL` and no other filter); :meth:`finish` stores the
    last, partial chunk and waits for the others."""

    def __init__(self, ds: h5py.Dataset, pool: ThreadPoolExecutor) -> None:
        assert ds.chunks is not None and ds.compression == "gzip" and ds.shape[0] == 0
        self._ds, self._pool = ds, pool
        self._rows = ds.chunks[0]
        self._gathered: list[np.ndarray] = []
        self._n_gathered = 0
        self._n_rows = 0
        self._next_chunk = 0
        self._pending: deque[tuple[int, Future[bytes]]] = deque()

    def append(self, rows: np.ndarray) -> None:
        """Add ``rows`` (their count along the first axis) after the rows written so far."""
        rows = np.ascontiguousarray(rows, self._ds.dtype)
        self._n_rows += len(rows)
        self._ds.resize(self._n_rows, axis=0)
        self._gathered.append(rows)
        self._n_gathered += len(rows)
        if self._n_gathered >= self._rows:  # one copy of the gathered rows, cut into chunks
            gathered = np.concatenate(self._gathered)
            full = len(gathered) - len(gathered) % self._rows
            for start in range(0, full, self._rows):
                self._submit(gathered[start : start + self._rows])
            self._gathered, self._n_gathered = [gathered[full:]], len(gathered) - full
        self._store(wait=False)

    def finish(self) -> None:
        """Store the last chunk (zero-padded past the last row) and every pending one."""
        if self._n_gathered:
            last = np.zeros((self._rows, *self._ds.shape[1:]), self._ds.dtype)
            last[: self._n_gathered] = np.concatenate(self._gathered)
            self._submit(last)
            self._gathered, self._n_gathered = [], 0
        self._store(wait=True)

    def _submit(self, chunk: np.ndarray) -> None:
        """Compress ``chunk`` (rows of an array of this writer's own, never the caller's) on a
        thread."""
        self._pending.append((self._next_chunk, self._pool.submit(_deflate, chunk)))
        self._next_chunk += 1

    def _store(self, wait: bool) -> None:
        """Write the compressed chunks that are ready, in order (all of them with ``wait``,
        the oldest while more than :data:`MAX_PENDING` are pending)."""
        while self._pending and (
            wait or self._pending[0][1].done() or len(self._pending) > MAX_PENDING
        ):
            index, compressed = self._pending.popleft()
            offset = (index * self._rows,) + (0,) * (self._ds.ndim - 1)
            self._ds.id.write_direct_chunk(offset, compressed.result())
