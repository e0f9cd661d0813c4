"""Sessions, recovered sessions and cloud files open in other HDF5 readers: Debian's h5dump
(HDF5 1.10, the library MATLAB and HDFView bundle) and h5py built on HDF5 1.14; `vbfe upgrade`
rewrites a session of the earlier format (HDF5 2.0 object versions, lzf images) for them."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from tests.cli import vbfe
from tests.paths import REPO
from vbfe.acquire import SessionWriter, finalize_session, recover_session
from vbfe.common import files
from vbfe.drivers.samples import ForceSample, StereoFrame
from vbfe.recon.clouds import FRAME_TABLES, CloudWriter

H5DUMP = shutil.which("h5dump")
needs_h5dump = pytest.mark.skipif(H5DUMP is None, reason="h5dump (Debian's hdf5-tools) missing")
CALIBRATION = "%YAML:1.0\n---\nimage_width: 64\nimage_height: 48\nB_m: 4.0e-3\n"
SIZE = (64, 48)


def write_session(path: Path, n_frames: int = 4, compression: str | None = None) -> Path:
    """A closed session of noisy frames and 1 kHz forces, written as the recorder writes."""
    rng = np.random.default_rng(0)
    options = {"compression": compression} if compression else {}
    writer = SessionWriter(path, SIZE, calibration_yaml=CALIBRATION, **options)
    for i in range(n_frames):
        left, right = (rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(2))
        writer.append_frames([StereoFrame(left, right, i, 1000 + i, 2000 + i)])
        writer.append_forces(
            [ForceSample(rng.normal(size=3), 10 * i + j, 10 * i + j, 3000 + j) for j in range(10)]
        )
        writer.flush()
    writer.close()
    finalize_session(path, {"end_reason": "test"})
    return path


def h5dump_values(path: Path, dataset: str, *subset: str) -> np.ndarray:
    """A dataset's values (or a ``-s START -c COUNT`` subset) as h5dump prints them."""
    out = path.with_name(f"{path.name}.dump.txt")
    args = [H5DUMP, "-y", "-w", "0", "-m", "%.17g", "-o", str(out), "-d", dataset, *subset]
    done = subprocess.run([*args, str(path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "error" not in done.stdout + done.stderr, done.stderr
    return np.array(out.read_text().replace(",", " ").split(), dtype=np.float64)


def h5dump_text(path: Path, what: str) -> str:
    done = subprocess.run([H5DUMP, *what.split(), str(path)], capture_output=True, text=True)
    assert done.returncode == 0 and "error" not in done.stdout + done.stderr, done.stderr
    return done.stdout


def assert_h5dump_reads_session(path: Path) -> None:
    """Force, timestamps, one left and one right image and the calibration, as h5py reads them."""
    with h5py.File(path, "r") as f:
        force, t_host = f["force/force_n"][:], f["camera/t_host_ns"][:]
        left, right = f["camera/left"][1], f["camera/right"][2]
        compression = f.attrs["compression"]
    np.testing.assert_array_equal(h5dump_values(path, "/force/force_n"), force.ravel())
    np.testing.assert_array_equal(h5dump_values(path, "/camera/t_host_ns"), t_host)
    one = ["-s", "1,0,0,0", "-c", "1,48,64,3"]
    np.testing.assert_array_equal(h5dump_values(path, "/camera/left", *one), left.ravel())
    two = ["-s", "2,0,0,0", "-c", "1,48,64,3"]
    np.testing.assert_array_equal(h5dump_values(path, "/camera/right", *two), right.ravel())
    assert "B_m: 4.0e-3" in h5dump_text(path, "-d /calibration_yaml")
    assert f'"{compression}"' in h5dump_text(path, "-a /compression")


@needs_h5dump
def test_h5dump_reads_a_fresh_session(tmp_path):
    path = write_session(tmp_path / "s.h5")
    assert_h5dump_reads_session(path)
    with h5py.File(path, "r") as f:  # the default image codec is one stock HDF5 decodes
        assert f["camera/left"].compression == "gzip" and f["camera/left"].fletcher32


def recovered_session(folder: Path) -> Path:
    """A session whose writing process was SIGKILLed after five flushes, recovered."""
    killed = folder / "killed.h5"
    script = textwrap.dedent(
        f"""
        import os, signal, numpy as np
        from tests.acquire.test_session_portable import (
            CALIBRATION, SIZE, ForceSample, SessionWriter, StereoFrame)
        writer = SessionWriter({str(killed)!r}, SIZE, calibration_yaml=CALIBRATION)
        rng = np.random.default_rng(1)
        for i in range(5):
            pair = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(2)]
            writer.append_frames([StereoFrame(*pair, i, 1000 + i, 2000 + i)])
            writer.append_forces([ForceSample(rng.normal(size=3), i, i, 3000 + i)])
            writer.flush()
        writer.append_frames([StereoFrame(*pair, 5, 1005, 2005)])  # never flushed
        os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO)
    assert done.returncode == -signal.SIGKILL
    recovered, _ = recover_session(killed, folder / "recovered.h5")
    with h5py.File(recovered, "r") as f:
        assert f["camera/left"].shape[0] == 5 and f.attrs["complete"]
    return recovered


def cloud_file(folder: Path) -> Path:
    """A finished cloud file of two frames, as `vbfe reconstruct` writes them."""
    rng = np.random.default_rng(2)
    writer = CloudWriter(folder / "s.clouds.h5", {"f_px": 412.5, "B_m": 0.004}, CALIBRATION)
    for i in range(2):
        stats = {
            name: np.zeros(4) if name in ("disparity_px", "match_counts") else 0.5
            for name in FRAME_TABLES
            if name not in ("frame_index", "t_host_ns")
        }
        points = rng.normal(size=(500, 3)).astype(np.float32)
        writer.append(i, 100 + i, points, rng.integers(0, 256, (500, 3), dtype=np.uint8), stats)
    return writer.finish()


@needs_h5dump
def test_h5dump_reads_a_session_recovered_after_sigkill(tmp_path):
    assert_h5dump_reads_session(recovered_session(tmp_path))


@needs_h5dump
def test_h5dump_reads_a_cloud_file(tmp_path):
    path = cloud_file(tmp_path)
    with h5py.File(path, "r") as f:
        points, offsets = f["points"][:], f["offsets"][:]
    np.testing.assert_array_equal(h5dump_values(path, "/points"), points.ravel())
    np.testing.assert_array_equal(h5dump_values(path, "/offsets"), offsets)
    assert "412.5" in h5dump_text(path, "-a /f_px")


def write_earlier_session(path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A session as vbfe wrote them before (newest HDF5 object versions, lzf images)."""
    with monkeypatch.context() as patch:
        patch.setattr(files, "HDF5_LIBVER", "latest")
        return write_session(path, compression="lzf")


def all_items(f: h5py.File) -> dict[str, object]:
    """Every object's attributes and every dataset's values, by HDF5 path."""
    items: dict[str, object] = {"/": dict(f.attrs)}

    def visit(name: str, obj: object) -> None:
        attrs = dict(obj.attrs)  # type: ignore[attr-defined]
        value = obj[()] if isinstance(obj, h5py.Dataset) else None
        items[name] = (attrs, value)

    f.visititems(visit)
    return items


@needs_h5dump
def test_upgrade_makes_an_earlier_session_readable_keeping_everything(tmp_path, monkeypatch):
    old = write_earlier_session(tmp_path / "old.h5", monkeypatch)
    fails = subprocess.run([H5DUMP, "-d", "/force/force_n", str(old)], capture_output=True)
    assert fails.returncode != 0  # the problem: HDF5 1.10 cannot read the earlier format
    before = old.read_bytes()
    refused = vbfe(*["upgrade", str(old)])
    assert refused.returncode == 2 and "--overwrite" in refused.stderr
    assert old.read_bytes() == before  # never in place without --overwrite

    done = vbfe(*["upgrade", str(old), "-o", str(tmp_path / "new.h5")])
    assert done.returncode == 0, done.stderr
    new = tmp_path / "new.h5"
    assert_h5dump_reads_session(new)
    with h5py.File(old, "r") as a, h5py.File(new, "r") as b:
        x, y = all_items(a), all_items(b)
        assert x.keys() == y.keys()
        assert b.attrs["compression"] == "gzip" and b.attrs["upgraded_from_compression"] == "lzf"
        for name in x:
            ax, vx = x[name] if name != "/" else (x[name], None)  # type: ignore[misc]
            ay, vy = y[name] if name != "/" else (y[name], None)  # type: ignore[misc]
            changed = {"compression", "upgraded_from_compression", "upgraded_utc_ns", "upgraded_by"}
            assert {k for k in ay if k not in changed} == set(ax) - {"compression"}, name
            for key in set(ax) - changed:
                np.testing.assert_array_equal(np.asarray(ax[key]), np.asarray(ay[key]))
            if isinstance(vx, np.ndarray):
                np.testing.assert_array_equal(vx, vy)
            else:
                assert vx == vy, name

    again = vbfe(*["upgrade", str(old), "-o", str(new)])
    assert again.returncode == 2 and "already exists" in again.stderr
    done = vbfe(*["upgrade", str(old), "--overwrite"])
    assert done.returncode == 0, done.stderr
    assert_h5dump_reads_session(old)


@pytest.mark.slow
def test_h5py_on_hdf5_1_14_reads_sessions_recovered_sessions_and_clouds(tmp_path, monkeypatch):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    python = venv / "bin" / "python"
    # numpy from this environment (appended after the venv's own h5py in sys.path)
    site = next(Path(p) for p in sys.path if p.endswith("site-packages"))
    venv_site = next((venv / "lib").glob("python3*/site-packages"))
    (venv_site / "project-numpy.pth").write_text(str(site))
    install = subprocess.run(
        [python, "-m", "pip", "install", "-q", "--no-deps", "h5py<3.13"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if install.returncode != 0:
        pytest.skip(f"h5py<3.13 cannot be installed here: {install.stderr.strip()[-200:]}")
    session = write_session(tmp_path / "s.h5")
    upgraded = tmp_path / "upgraded.h5"
    old = write_earlier_session(tmp_path / "old.h5", monkeypatch)
    assert vbfe(*["upgrade", str(old), "-o", str(upgraded)]).returncode == 0
    sessions = [session, recovered_session(tmp_path), upgraded]
    clouds = cloud_file(tmp_path)
    expected = []
    for path in sessions:
        with h5py.File(path, "r") as f:
            expected.append(float(f["force/force_n"][:].sum() + f["camera/left"][:].sum()))
    with h5py.File(clouds, "r") as f:
        expected.append(float(f["points"][:].sum()))
    read = textwrap.dedent(
        """
        import sys, h5py
        assert h5py.version.hdf5_version.startswith("1.14"), h5py.version.hdf5_version
        for path in sys.argv[1:]:
            with h5py.File(path, "r") as f:
                if "points" in f:
                    print(float(f["points"][:].sum()))
                else:
                    print(float(f["force/force_n"][:].sum() + f["camera/left"][:].sum()))
        """
    )
    done = subprocess.run(
        [python, "-c", read, *map(str, [*sessions, clouds])],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": ""},
    )
    assert done.returncode == 0, done.stderr
    assert [float(v) for v in done.stdout.split()] == expected


@needs_h5dump
@pytest.mark.parametrize("compression", ["zstd", "blosc-lz4"])
def test_h5dump_reads_plugin_codecs_with_the_documented_plugin_path(
    tmp_path, monkeypatch, compression
):
    import hdf5plugin

    path = write_session(tmp_path / "s.h5", compression=compression)
    monkeypatch.setenv("HDF5_PLUGIN_PATH", hdf5plugin.PLUGIN_PATH)  # docs/how-to/other-readers.md
    assert_h5dump_reads_session(path)
