"""Portable copies of vbfe HDF5 files: every group, dataset and attribute re-created in the
portable file format (:data:`vbfe.common.files.HDF5_LIBVER`), raw images under a chosen codec.

HDF5's own object copy (``H5Ocopy``) keeps each object's messages in the version they were
written with, so a file written with newer format versions stays unreadable to older HDF5 after
a copy: here each dataset is created anew in the destination and its values copied over.
:func:`upgrade_file` is ``vbfe upgrade``; recovery uses :func:`copy_tree` too.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from vbfe.acquire.session.layout import COMPRESSIONS, image_filter, session_streams
from vbfe.acquire.session.reader import SessionReader, open_session_file
from vbfe.common.errors import SessionError
from vbfe.common.files import (
    SESSION_FORMAT,
    WriterLock,
    commit,
    create_hdf5,
    partial_path,
    require_free_space,
)
from vbfe.common.version import __version__

log = logging.getLogger(__name__)

_BLOCK_BYTES = 32 << 20  # values copied (and compared) this many bytes at a time
# attributes an upgrade changes or adds (everything else is kept as it was)
UPGRADE_ATTRS = ("compression", "upgraded_utc_ns", "upgraded_by", "upgraded_from_compression")


def _copy_attrs(src: Any, dst: Any) -> None:
    for key in src.attrs:
        dst.attrs.create(key, src.attrs[key], dtype=src.attrs.get_id(key).dtype)


def _filters(ds: h5py.Dataset, image_keywords: dict[str, Any] | None) -> dict[str, Any]:
    """``create_dataset`` keywords for a copy of ``ds``: its checksum; images under
    ``image_keywords``; any other compressed data under deflate (built into every HDF5)."""
    keywords: dict[str, Any] = {"fletcher32": ds.fletcher32}
    if image_keywords is not None:
        keywords.update(image_keywords)
    elif _compressed(ds):
        keywords.update(compression="gzip", compression_opts=1, shuffle=ds.dtype.itemsize > 1)
    return keywords


def _compressed(ds: h5py.Dataset) -> bool:
    """Whether ``ds`` has a filter other than HDF5's checksum and shuffle (built in or a
    plugin's)."""
    plist = ds.id.get_create_plist()
    ids = {plist.get_filter(i)[0] for i in range(plist.get_nfilters())}
    return bool(ids - {h5py.h5z.FILTER_FLETCHER32, h5py.h5z.FILTER_SHUFFLE})


def _row_blocks(ds: h5py.Dataset) -> Iterator[slice | tuple[()]]:
    """Slices of whole rows of ``ds`` about :data:`_BLOCK_BYTES` each (a scalar: ``()``)."""
    if ds.shape == ():
        yield ()
        return
    n = ds.shape[0]
    row = max(int(np.prod(ds.shape[1:], dtype=np.int64)) * ds.dtype.itemsize, 1)
    step = max(_BLOCK_BYTES // row, 1)
    if ds.chunks:
        step = max(step // ds.chunks[0], 1) * ds.chunks[0]
    for start in range(0, n, step):
        yield slice(start, min(start + step, n))


def _copy_dataset(ds: h5py.Dataset, dst: h5py.Group, image_keywords: dict | None) -> None:
    name = ds.name.rsplit("/", 1)[-1]
    if ds.shape == () or ds.chunks is None:
        out = dst.create_dataset(name, data=ds[()], dtype=ds.dtype)
    else:
        out = dst.create_dataset(
            name,
            shape=ds.shape,
            maxshape=ds.maxshape,
            chunks=ds.chunks,
            dtype=ds.dtype,
            **_filters(ds, image_keywords),
        )
        for rows in _row_blocks(ds):
            out[rows] = ds[rows]
    _copy_attrs(ds, out)


def copy_tree(src: h5py.Group, dst: h5py.Group, images: dict[str, dict[str, Any]]) -> None:
    """Copy the attributes, groups and datasets of ``src`` into ``dst``, each re-created in
    ``dst``'s file format; the datasets named in ``images`` (full HDF5 paths) get those
    ``create_dataset`` keywords."""
    _copy_attrs(src, dst)
    for name, item in src.items():
        if isinstance(item, h5py.Group):
            copy_tree(item, dst.create_group(name), images)
        elif isinstance(item, h5py.Dataset):
            _copy_dataset(item, dst, images.get(item.name))


def image_datasets(f: h5py.File, compression: str) -> dict[str, dict[str, Any]]:
    """The raw image datasets of a session (empty for other files), each with the keywords of
    ``compression``."""
    if f.attrs.get("format") != SESSION_FORMAT:
        return {}
    keywords = image_filter(compression)
    return {
        f"/{spec.name}/{column.name}": keywords
        for spec in session_streams(f)
        for column in spec.columns
        if column.image
    }


def _differences(a: Any, b: Any, skip: tuple[str, ...]) -> Iterator[str]:
    """What differs between two groups (attributes, members, dataset values), recursively."""
    for key in set(a.attrs) | set(b.attrs):
        if key in skip:
            continue
        if key not in a.attrs or key not in b.attrs:
            yield f"{a.name} attribute {key} missing"
        elif not np.array_equal(np.asarray(a.attrs[key]), np.asarray(b.attrs[key])):
            yield f"{a.name} attribute {key} differs"
    if not isinstance(a, h5py.Group):
        return
    if set(a) != set(b):
        yield f"{a.name} members differ: {sorted(set(a) ^ set(b))}"
        return
    for name in a:
        x, y = a[name], b[name]
        if isinstance(x, h5py.Dataset):
            if x.shape != y.shape or x.dtype != y.dtype:
                yield f"{x.name}: shape or type differs"
            elif any(not np.array_equal(x[rows], y[rows]) for rows in _row_blocks(x)):
                yield f"{x.name}: values differ"
        yield from _differences(x, y, ())


def upgrade_file(
    path: str | Path, out_path: str | Path, compression: str, overwrite: bool = False
) -> Path:
    """Rewrite a vbfe HDF5 file (a session or a cloud file, from any vbfe version) into the
    portable format with raw images under ``compression``; every dataset and attribute kept,
    the copy compared value by value with ``path`` before it is renamed onto ``out_path``
    (which may be ``path`` itself: then the old file is replaced only after that check).

    :raises SessionError: an unknown compression, a session still being written or never
        closed (recover it first), an existing output without ``overwrite``, or a copy that
        differs from its source.
    """
    path, out_path = Path(path), Path(out_path)
    if compression not in COMPRESSIONS:
        raise SessionError(f"unknown compression {compression!r}; choose one of {COMPRESSIONS}")
    if out_path.exists() and not overwrite:
        raise SessionError(f"{out_path} already exists; pass --overwrite to replace it")
    require_free_space(out_path.parent, path.stat().st_size, f"the upgraded copy {out_path}")
    tmp = partial_path(out_path)
    with WriterLock(path):
        src, clean = open_session_file(path)
        with src:
            if not str(src.attrs.get("format", "")).startswith("vbfe-"):
                raise SessionError(
                    f"{path} is not a vbfe session or cloud file; nothing to upgrade"
                )
            if not clean:
                raise SessionError(
                    f"{path} was not closed cleanly; recover it first (vbfe inspect {path} "
                    "--recover OUT.h5), then upgrade the recovered copy"
                )
            if src.attrs.get("format") == SESSION_FORMAT:
                with SessionReader(path):  # a damaged session fails here, naming what is wrong
                    pass
            images = image_datasets(src, compression)
            try:
                with create_hdf5(tmp) as dst:
                    copy_tree(src, dst, images)
                    if images:
                        dst.attrs["upgraded_from_compression"] = str(src.attrs.get("compression"))
                        dst.attrs["compression"] = compression
                    dst.attrs["upgraded_utc_ns"] = time.time_ns()
                    dst.attrs["upgraded_by"] = f"vbfe {__version__}"
                with h5py.File(tmp, "r") as check:
                    problem = next(iter(_differences(src, check, UPGRADE_ATTRS)), None)
                if problem is not None:
                    raise SessionError(f"the upgraded copy of {path} differs ({problem}); kept")
            except BaseException:
                tmp.unlink(missing_ok=True)
                raise
    log.info("upgraded %s into %s (images: %s)", path, out_path, compression if images else "-")
    return commit(tmp, out_path)
