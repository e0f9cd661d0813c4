"""Camera images as deflate chunks every HDF5 decodes, at a fraction of HDF5's own cost.

HDF5's deflate filter runs zlib at a compression level with the default strategy; on camera
images (sensor noise in every pixel) its string matching finds little and costs most of the
time. The chunks here are zlib streams made with the Huffman-only strategy, which any inflate
decodes the same way, followed by HDF5's Fletcher-32 checksum, and written with HDF5's direct
chunk write: a dataset created with ``compression="gzip"`` and ``fletcher32=True`` reads them
back through its ordinary filter pipeline (h5py, h5dump, MATLAB, HDFView). On the recorder's
noisy 640x360 frames this is about half the CPU of HDF5's level 1 and compresses slightly
better (benchmarks/bench_record.py). A writer that has fallen behind stores chunks instead
(``stored=True``: deflate's stored blocks, still decoded by every inflate): about a tenth of
the CPU for chunks about twice the size, so it catches up rather than lose frames.
"""

from __future__ import annotations

import zlib

import h5py
import numpy as np
from numba import njit

_BLOCK_WORDS = 360  # HDF5's Fletcher-32 folds its sums every 360 16-bit words


@njit(cache=True, nogil=True)
def _fletcher32(words: np.ndarray, odd_byte: int, has_odd: bool) -> int:  # pragma: no cover
    """HDF5's ``H5_checksum_fletcher32`` of big-endian 16-bit ``words`` (and a last odd byte)."""
    sum1 = np.uint32(0)
    sum2 = np.uint32(0)
    i, n = 0, words.size
    while i < n:
        end = min(i + _BLOCK_WORDS, n)
        while i < end:
            sum1 = np.uint32(sum1 + np.uint32(words[i]))
            sum2 = np.uint32(sum2 + sum1)
            i += 1
        sum1 = (sum1 & np.uint32(0xFFFF)) + (sum1 >> np.uint32(16))
        sum2 = (sum2 & np.uint32(0xFFFF)) + (sum2 >> np.uint32(16))
    if has_odd:
        sum1 = np.uint32(sum1 + (np.uint32(odd_byte) << np.uint32(8)))
        sum2 = np.uint32(sum2 + sum1)
        sum1 = (sum1 & np.uint32(0xFFFF)) + (sum1 >> np.uint32(16))
        sum2 = (sum2 & np.uint32(0xFFFF)) + (sum2 >> np.uint32(16))
    sum1 = (sum1 & np.uint32(0xFFFF)) + (sum1 >> np.uint32(16))
    sum2 = (sum2 & np.uint32(0xFFFF)) + (sum2 >> np.uint32(16))
    return int((sum2 << np.uint32(16)) | sum1)


def fletcher32(data: bytes) -> int:
    """The Fletcher-32 checksum HDF5 appends to a filtered chunk."""
    even = len(data) - len(data) % 2
    words = np.frombuffer(data, dtype=">u2", count=even // 2).astype(np.uint16)
    return _fletcher32(words, data[-1] if len(data) % 2 else 0, bool(len(data) % 2))


def deflate_chunk(image: np.ndarray, stored: bool = False) -> bytes:
    """The stored bytes of one image chunk under the pipeline deflate + Fletcher-32
    (``stored``: deflate's uncompressed blocks, the least CPU)."""
    encoder = (
        zlib.compressobj(0, zlib.DEFLATED, 15, 8)
        if stored
        else zlib.compressobj(1, zlib.DEFLATED, 15, 8, zlib.Z_HUFFMAN_ONLY)
    )
    body = encoder.compress(np.ascontiguousarray(image).data) + encoder.flush()
    return body + fletcher32(body).to_bytes(4, "little")


def write_deflated(ds: h5py.Dataset, row: int, image: np.ndarray, stored: bool = False) -> None:
    """Store ``image`` as row ``row`` (one chunk) of a dataset created with deflate and
    Fletcher-32, in that order (h5py's order); ``stored``: uncompressed deflate blocks."""
    ds.id.write_direct_chunk((row,) + (0,) * image.ndim, deflate_chunk(image, stored))
