"""Rows appended across chunk boundaries, compressed on threads, read back by HDF5's filter."""

import re
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor

import h5py
import numpy as np
import pytest

from vbfe.recon.deflated_rows import LEVEL, DeflatedRows


def test_rows_across_chunks_read_back_through_the_deflate_filter(tmp_path):
    rng = np.random.default_rng(0)
    parts = [rng.normal(size=(n, 3)).astype(np.float32) for n in (3, 7, 0, 12, 1, 5)]
    path = tmp_path / "rows.h5"
    with h5py.File(path, "w") as f, ThreadPoolExecutor(2) as pool:
        ds = f.create_dataset(
            "points", (0, 3), np.float32, maxshape=(None, 3), chunks=(5, 3),
            compression="gzip", compression_opts=LEVEL,
        )  # fmt: skip
        rows = DeflatedRows(ds, pool)
        for part in parts:
            rows.append(part)
        rows.finish()
    expected = np.concatenate(parts)  # 28 rows: five full chunks and a partial one
    with h5py.File(path, "r") as f:
        assert f["points"].compression == "gzip" and f["points"].shape == (28, 3)
        np.testing.assert_array_equal(f["points"][()], expected)
        np.testing.assert_array_equal(f["points"][24:28], expected[24:])
    if shutil.which("h5dump") is None:
        pytest.skip("h5dump (Debian's hdf5-tools) is not installed")
    dumped = subprocess.run(
        ["h5dump", "-d", "/points", "-s", "27,0", "-c", "1,3", "-m", "%.9g", str(path)],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    values = re.findall(r"\(27,\d\): ([-+\d.e]+)", dumped)
    np.testing.assert_array_equal(np.array(values, np.float32), expected[27])
