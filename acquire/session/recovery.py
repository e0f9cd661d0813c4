"""Recovering a session whose recorder died: a clean, finalized copy of what was flushed."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import h5py
import numpy as np

from vbfe.acquire.session.layout import COMPRESSIONS, DEFAULT_COMPRESSION, session_streams
from vbfe.acquire.session.portable import copy_tree, image_datasets
from vbfe.acquire.session.reader import SessionReader, consistent_rows, open_session_file
from vbfe.acquire.session.writer import RESERVE_BYTES, finish_file
from vbfe.common.errors import SessionError
from vbfe.common.files import (
    SESSION_FORMAT,
    commit,
    create_hdf5,
    partial_path,
    require_free_space,
)


def _trim(group: h5py.Group, keys: Sequence[str], n: int) -> int:
    """Cut the datasets ``keys`` of ``group`` to ``n`` rows; returns the rows removed."""
    removed = 0
    for key in keys:
        if key in group and group[key].shape[0] > n:
            removed = max(removed, group[key].shape[0] - n)
            group[key].resize(n, axis=0)
    return removed


def _keep_consistent_rows(f: h5py.File) -> dict[str, int]:
    """Cut every stream of a copied session to its rows with consistent timestamps (a writer
    that died mid-write can leave rows that exist but were never filled); returns the rows
    dropped per stream."""
    dropped = {}
    for spec in session_streams(f):
        group = f[spec.name]
        n = consistent_rows(group)
        dropped[spec.name] = _trim(group, spec.keys(), n)
        for blob in spec.blobs:  # bytes up to the end of the last row kept
            index = group[f"{blob}_index"]
            _trim(group, [blob], int(index[n - 1].sum()) if n else 0)
    for name in ("gaps", "clock_pairs"):
        column = 4 if name == "gaps" else 1  # t_host_ns
        rows = f[name][:]
        valid = np.flatnonzero(rows[:, column] <= 0) if len(rows) else np.zeros(0, int)
        _trim(f, [name], int(valid[0]) if len(valid) else len(rows))
    return dropped


def recover_session(
    path: str | Path, out_path: str | Path, overwrite: bool = False
) -> tuple[Path, dict[str, int]]:
    """Copy a session whose recorder died (SWMR write flag still set) into a clean, finalized
    file ``out_path``: every row up to the last flush whose timestamps are consistent, plus
    clock fits. Returns the new file and the rows dropped per stream. The copy is written under
    a temporary name and renamed when complete."""
    out_path = Path(out_path)
    if out_path.exists() and not overwrite:
        raise SessionError(f"{out_path} already exists; choose a new file for the recovered copy")
    if not out_path.parent.is_dir():
        raise SessionError(
            f"cannot recover into {out_path}: folder {out_path.parent} does not exist"
        )
    with SessionReader(path):  # a damaged file fails here, naming what is wrong
        pass
    require_free_space(
        out_path.parent, Path(path).stat().st_size + RESERVE_BYTES, f"the recovered copy {out_path}"
    )
    src, _ = open_session_file(path)
    tmp = partial_path(out_path)
    try:
        with src, create_hdf5(tmp) as dst:
            if src.attrs.get("format") != SESSION_FORMAT:
                raise SessionError(f"{path} is not a vbfe session; nothing to recover")
            stored = str(src.attrs.get("compression"))  # images keep their codec where known
            codec = stored if stored in COMPRESSIONS else DEFAULT_COMPRESSION
            copy_tree(src, dst, image_datasets(src, codec))
            dropped = _keep_consistent_rows(dst)
            finish_file(
                dst,
                {
                    "end_reason": "recovered: the recording was interrupted",
                    "recovered_from": str(Path(path).absolute()),
                    **{f"{s}_recovery_dropped": n for s, n in dropped.items()},
                },
                None,
            )
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise SessionError(
            f"{path} cannot be recovered (damaged beyond its last flush?): {exc}"
        ) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return commit(tmp, out_path), dropped
