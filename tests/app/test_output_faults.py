"""Command-level faults through the real CLI: full and read-only folders (a tmpfs mounted by
the test, skipped where mounting is not allowed), Ctrl-C and SIGTERM while workers run, a
second writer on a session being recorded, a session read while it is finalized."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.paths import REPO
from vbfe.acquire import SessionReader, record_session, store_analysis
from vbfe.cli.main import main
from vbfe.common.errors import OutputError
from vbfe.common.files import atomic_path
from vbfe.rig_config import builtin_rig
from vbfe.truth import calibration_from_rig, true_rig


def vbfe(*args: str) -> subprocess.Popen:
    """``vbfe ARGS`` in a subprocess of its own session, with Ctrl-C at its default action
    (a background job would otherwise pass SIGINT on ignored)."""
    return subprocess.Popen(
        [sys.executable, "-m", "vbfe.cli.main", *map(str, args)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def one_error(err: str, *words: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("vbfe ")]
    assert len(lines) == 1 and "Traceback" not in err and "HDF5-DIAG" not in err, err
    assert all(w.lower() in lines[0].lower() for w in words), lines[0]
    return lines[0]


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name != "fill")


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """A 6 s bench session (320x180, 10 fps) with its calibration stored, and as cal.yaml."""
    folder = tmp_path_factory.mktemp("faults")
    config = builtin_rig({"bench": dict(width=320, height=180, fps=10.0, seed=3, distortion=False)})
    calibration = calibration_from_rig(true_rig(config))
    calibration.save(folder / "cal.yaml")
    path = folder / "run.h5"
    record_session(config, path, duration_s=6.0, calibration_yaml=calibration.to_yaml_text())
    return path


def _mount(folder: Path, size: str) -> None:
    folder.mkdir()
    result = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
        capture_output=True,
        text=True,
    )
    if result.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({result.stderr.strip()}): run as root")


@pytest.fixture
def disks(tmp_path):
    """A full 2 MiB tmpfs, a 6 MiB one with room for a few clouds, and a read-only tmpfs."""
    full, small, ro = tmp_path / "full", tmp_path / "small", tmp_path / "ro"
    mounted = []
    try:
        for folder, size in ((full, "2m"), (small, "6m"), (ro, "1m")):
            _mount(folder, size)
            mounted.append(folder)
        (full / "fill").write_bytes(bytes(1900 << 10))
        subprocess.run(["mount", "-o", "remount,ro", str(ro)], check=True)
        yield full, small, ro
    finally:
        for folder in mounted:
            subprocess.run(["umount", str(folder)], check=True)


def test_full_and_read_only_folders_give_one_line_exit_2_and_leave_nothing(session, disks, capsys):
    full, small, ro = disks
    # the clouds fill the 6 MiB disk part way: stopped before HDF5 meets it (no native crash)
    proc = vbfe("reconstruct", session, "--out", small / "c.clouds.h5", "--workers", "2")
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    one_error(err, "no space", str(small))
    assert leftovers(small) == []

    cal = session.parent / "cal.yaml"
    for argv, words in (
        (["reconstruct", session, "--out", full / "c.clouds.h5"], ("no space",)),
        (["inspect", session, "--recover", full / "r.h5"], ("no space",)),
        (["train", session, "--out", full / "m.pt"], ("no space",)),
        (["dataset", session.parent, "--manifest", ro / "m.csv"], ("read-only",)),
        (["verify-sync", session, "--plot", ro / "p.png", "--no-store"], ("read-only",)),
        (["calibrate", "export", cal, "--format", "ros", "--out-dir", ro], ("read-only",)),
        (["record", ro / "x.h5", "--duration", "0.2"], ("not writable",)),
    ):
        assert main([str(a) for a in argv]) == 2, argv
        one_error(capsys.readouterr().err, *words)
    assert leftovers(full) == [] and leftovers(ro) == []


@pytest.mark.parametrize(
    "command, sig, code",
    [
        ("reconstruct", signal.SIGINT, 130),
        ("reconstruct", signal.SIGTERM, 143),
        ("verify-sync", signal.SIGTERM, 143),
    ],
)
def test_signals_stop_commands_and_their_workers_within_a_second(
    session, tmp_path, command, sig, code
):
    if command == "reconstruct":
        proc = vbfe("reconstruct", session, "--out", tmp_path / "c.clouds.h5", "--workers", "2")
    else:  # two sessions checked in two worker processes, each writing its plot
        for name in ("a.h5", "b.h5"):
            (tmp_path / name).write_bytes(session.read_bytes())
        proc = vbfe("verify-sync", tmp_path / "a.h5", tmp_path / "b.h5", "--workers", "2")
    before = sorted(tmp_path.iterdir())
    deadline = time.monotonic() + 60
    workers: list[str] = []
    while len(workers) < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
        workers = subprocess.run(
            ["pgrep", "-P", str(proc.pid)], capture_output=True, text=True
        ).stdout.split()
    time.sleep(1.0)  # workers busy
    assert proc.poll() is None
    sent = time.monotonic()
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:  # hung: fail without leaving it to load the next tests
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail(f"vbfe {command} did not stop within 30 s of {sig.name}")
    assert time.monotonic() - sent < 2.0  # a second on a quiet machine
    assert proc.returncode == code, err
    one_error(err, "interrupted" if sig == signal.SIGINT else "terminated")
    assert sorted(tmp_path.iterdir()) == before  # no output, no temporary file
    time.sleep(0.2)
    alive = [
        pid
        for pid in workers
        if Path(f"/proc/{pid}").exists()
        and "Z" not in Path(f"/proc/{pid}/stat").read_text().split()[2]
    ]
    assert alive == []


def test_a_second_writer_is_refused_naming_the_first_and_readers_follow_the_recording(
    session, tmp_path, capsys
):
    rig = tmp_path / "rig.toml"
    rig.write_text(
        "[bench]\nwidth = 320\nheight = 180\nfps = 10.0\nrealtime = true\ndistortion = false\n"
    )
    path = tmp_path / "x.h5"
    first = vbfe(
        "record", path, "--duration", "4", "--config", rig, "--calib", session.parent / "cal.yaml"
    )
    lock = tmp_path / ".x.h5.lock"
    deadline = time.monotonic() + 60
    while not lock.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert (
        main(["record", str(path), "--overwrite", "--duration", "0.2", "--config", str(rig)]) == 2
    )
    one_error(capsys.readouterr().err, str(path), f"process {first.pid}")
    with pytest.raises(OutputError, match=f"process {first.pid}"):  # any other writer too
        store_analysis(path, {"note": "written meanwhile"})

    manifest = tmp_path / "m.csv"  # the growing session, listed three times
    manifest.write_text("path\nx.h5\nx.h5\n./x.h5\n")
    assert main(["reconstruct", str(manifest), "--workers", "2"]) == 0
    assert "1 of 1 sessions done" in capsys.readouterr().out
    _, err = first.communicate(timeout=60)
    assert first.returncode == 0, err
    assert not lock.exists()
    with SessionReader(path) as reader:
        assert reader.complete and reader.n_frames >= 30


def test_atomic_writes_leave_nothing_on_failure_and_take_the_umask_mode(tmp_path):
    target = tmp_path / "m.pt"
    target.write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise KeyboardInterrupt
    assert target.read_text() == "old" and len(list(tmp_path.iterdir())) == 1
    previous = os.umask(0o027)
    try:
        with atomic_path(target) as tmp:
            tmp.write_text("new")
    finally:
        os.umask(previous)
    assert target.read_text() == "new" and target.stat().st_mode & 0o777 == 0o640
    assert len(list(tmp_path.iterdir())) == 1
