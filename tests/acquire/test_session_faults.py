"""Faults a lab meets, through the real CLI: outputs onto inputs, readers open during a
recording, full disks, truncated and damaged files, signals, pacing and long live views."""

from __future__ import annotations

import hashlib
import os
import resource
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from tests.acquire.test_acquire_devices import write_bar_session
from tests.paths import REPO
from vbfe.acquire import AcquisitionStats, Recorder, SessionError, SessionReader
from vbfe.acquire.recording.listener import Listener
from vbfe.acquire.recording.record import session_recorder
from vbfe.acquire.session.inspect import inspect_session
from vbfe.cli.main import main
from vbfe.drivers.registry import open_rig
from vbfe.rig_config import load_rig

SMALL_BENCH = "[bench]\nwidth = 320\nheight = 180\n"  # small and quick to render


def vbfe(*args: str, **popen: object) -> subprocess.Popen:
    """Start ``vbfe ARGS`` in a subprocess (headless Qt)."""
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen"}
    return subprocess.Popen(
        [sys.executable, "-m", "vbfe.cli.main", *args],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **popen,
    )


def run_vbfe(*args: str, timeout: float = 120, **popen: object) -> tuple[int, str, str]:
    proc = vbfe(*args, **popen)
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err


def rig(tmp_path: Path, text: str, name: str = "rig.toml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("vbfe ")]


def assert_consistent_times(path: Path) -> SessionReader:
    """The session opens, every stream's host times are set and never step back."""
    reader = SessionReader(path)
    for stream in ("camera", "force"):
        t_host = reader.stream_times(stream)[1]
        assert len(t_host) > 0 and (t_host > 0).all() and (np.diff(t_host) >= 0).all()
    assert (np.diff(reader.frame_times_ns()) > 0).all()
    return reader


def _wait_for_frames(path: Path, proc: subprocess.Popen, timeout_s: float = 60) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
        try:
            with SessionReader(path) as s:
                if s.n_frames > 0:
                    return
        except SessionError:
            pass
    raise AssertionError("the recording did not start")


# -- outputs ----------------------------------------------------------------------------------
def test_outputs_never_replace_inputs_or_existing_files(tmp_path, capsys):
    session = tmp_path / "run.h5"
    write_bar_session(session, seconds=0.5)
    before = digest(session)
    other = tmp_path / "other.h5"
    other.write_bytes(b"keep me")

    for argv in (
        ["reconstruct", str(session), "--out", str(session)],
        ["reconstruct", str(session), "--out", str(session), "--overwrite"],
        ["inspect", str(session), "--recover", str(session), "--overwrite"],
        ["record", str(session), "--duration", "1"],
        ["train", str(session), "--out", str(session), "--overwrite"],
        ["verify-sync", str(session), "--plot", str(session), "--overwrite"],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert len(error_lines(err)) == 1 and str(session) in err, err
    assert main(["reconstruct", str(session), "--out", str(other)]) == 2
    assert "other.h5 already exists; pass --overwrite" in capsys.readouterr().err
    assert main(["evaluate", "model.pt", str(session), "--out", str(tmp_path)]) == 2
    assert "is not empty; pass --overwrite" in capsys.readouterr().err
    assert digest(session) == before and other.read_bytes() == b"keep me"

    assert main(["inspect", str(session), "--recover", str(other)]) == 2  # exists
    assert main(["inspect", str(session), "--recover", str(other), "--overwrite"]) == 0
    assert "recovered" in capsys.readouterr().out
    with SessionReader(other) as copy:
        assert copy.complete and copy.n_frames > 0
    assert digest(session) == before


def test_record_duration_must_be_positive(tmp_path, capsys):
    for value in ("0", "-5", "nan"):
        with pytest.raises(SystemExit) as stop:
            main(["record", str(tmp_path / "s.h5"), "--duration", value])
        assert stop.value.code == 2
        assert "--duration: must be a positive number" in capsys.readouterr().err
    assert not (tmp_path / "s.h5").exists()


# -- readers during a recording -----------------------------------------------------------------
def test_readers_open_for_the_whole_recording_do_not_stop_it_finalizing(tmp_path):
    path = tmp_path / "live.h5"
    config = rig(tmp_path, SMALL_BENCH + "fps = 10.0\nrealtime = true\n")
    proc = vbfe("record", str(path), "--config", config)
    _wait_for_frames(path, proc)
    held = SessionReader(path)  # open until the recording has ended
    plain = subprocess.Popen(  # a plain h5py reader in another process, with HDF5's file lock
        [
            sys.executable,
            "-c",
            "import h5py, sys; f = h5py.File(sys.argv[1], 'r', swmr=True); "
            "print(len(f['camera/seq']), flush=True); sys.stdin.read()",
            str(path),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert int(plain.stdout.readline()) > 0
    assert held.growing and not held.complete
    code, summary, _ = run_vbfe("inspect", str(path))  # another process, while it records
    assert code == 1 and "BEING RECORDED" in summary
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    seen = held.n_frames
    held.close()  # (a second open in this process would share its cached view of the file)
    with SessionReader(path) as done:
        assert done.complete and done.n_frames > seen > 0 and not done.growing
        assert done.attrs["end_reason"] == "stopped by operator"
    plain.communicate("", timeout=30)
    assert plain.returncode == 0


# -- full disk ----------------------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    """A 48 MiB tmpfs where mounting is allowed; otherwise a folder and a file-size limit that
    makes writes fail the same way (EFBIG instead of ENOSPC)."""
    mount = tmp_path / "disk"
    mount.mkdir()
    mounted = (
        subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=48m", "tmpfs", str(mount)], capture_output=True
        ).returncode
        == 0
    )
    if mounted:
        yield mount, None
        subprocess.run(["umount", str(mount)], check=True)
        return

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (48 << 20, 48 << 20))

    yield mount, limit


def test_full_disk_ends_the_recording_cleanly_with_consistent_times(tmp_path, small_disk):
    disk, limit = small_disk
    path = disk / "full.h5"
    config = rig(tmp_path, SMALL_BENCH + '[record]\ncompression = "none"\nmin_free_gb = 0.0\n')
    code, _, err = run_vbfe(
        "record", str(path), "--duration", "60", "--config", config, preexec_fn=limit
    )
    assert code == 2, err
    assert "Traceback" not in err and "Fatal" not in err
    lines = error_lines(err)
    assert len(lines) == 1 and f"writing {path} failed" in lines[0]
    assert "No space left on device" in lines[0] or "File too large" in lines[0]
    code, out, err = run_vbfe("inspect", str(path))  # a hang ends at the default timeout
    if limit is not None and code == 2:  # the size limit also stopped HDF5 closing the file
        assert error_lines(err) == [
            f"vbfe inspect: error: {path} is truncated: " + err.split("is truncated: ")[1].strip()
        ]
        return
    assert code in (0, 1), err  # complete (write failed) or not closed cleanly
    reader = assert_consistent_times(path)
    with reader:
        assert reader.n_frames > 30
        duration = float(out.split("duration")[1].split("s")[0])
        assert 1.0 < duration < 60


def test_free_space_guard_stops_and_finalizes_before_the_disk_is_full(tmp_path, small_disk):
    disk, limit = small_disk
    if limit is not None:
        pytest.skip("free space is only measurable on a real small file system")
    path = disk / "guarded.h5"
    # 640x360 uncompressed: 1.4 MB a frame, ~10 MB between two clock checks of free space on
    # a fast machine, as much as the whole stop margin; the guard must also count bytes
    config = rig(
        tmp_path,
        '[bench]\nwidth = 640\nheight = 360\n[record]\ncompression = "none"\nmin_free_gb = 0.04\n',
    )
    code, _, err = run_vbfe("record", str(path), "--duration", "60", "--config", config)
    assert code == 2, err
    assert "disk almost full" in err and "finalized with" in err
    # stopped within an eighth of the 10 MB margin (plus a frame): checked by volume written
    left_gb = float(err.split("disk almost full: ")[1].split(" GB left")[0])
    assert left_gb >= 0.0075, err
    with assert_consistent_times(path) as reader:
        assert reader.complete and reader.attrs["end_reason"].startswith("disk almost full")


class _StallOnce(Listener):
    """A listener whose first frames take 2 s: the frames queue up meanwhile (a busy machine)."""

    def __init__(self) -> None:
        self.stalled = False

    def on_frames(self, frames: Sequence[Any]) -> None:
        if not self.stalled:
            self.stalled = True
            time.sleep(2.0)


def test_a_backlog_of_frames_does_not_outrun_the_free_space_guard(tmp_path, small_disk):
    disk, limit = small_disk
    if limit is not None:
        pytest.skip("free space is only measurable on a real small file system")
    config = load_rig(
        rig(tmp_path, '[bench]\nwidth = 640\nheight = 360\n[record]\ncompression = "none"\n')
    ).updated({"record": {"min_free_gb": 0.04}})
    path = disk / "backlog.h5"
    stall = _StallOnce()
    recorder = session_recorder(config, path, open_rig(config), listeners=(stall,))
    recorder.start()
    with pytest.raises(SessionError, match="disk almost full") as raised:
        recorder.run(20.0)
    # the 2 s stall queued ~60 frames (83 MB, more than the disk): written in pieces, free
    # space read between them, the guard stopped within its 10 MB margin
    assert stall.stalled
    left_gb = float(str(raised.value).split("disk almost full: ")[1].split(" GB left")[0])
    assert left_gb >= 0.0075, raised.value
    with assert_consistent_times(path) as reader:
        assert reader.complete and reader.attrs["end_reason"].startswith("disk almost full")
        assert f"finalized with {reader.n_frames} frames" in str(raised.value)


# -- damaged files ------------------------------------------------------------------------------
KILLED_WRITER = """
import os, signal, sys
from tests.acquire.test_acquire_devices import bar_devices
from vbfe.acquire import SessionWriter
devices = bar_devices(speed=None)
devices.camera.open(); devices.trocar.open()
writer = SessionWriter(sys.argv[1], (64, 48), "lzf")
writer.append_frames([devices.camera.read(0.0) for _ in range(60)])
writer.append_forces([devices.trocar.read(0.0) for _ in range(2000)])
writer.flush()
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_recover_of_a_truncated_file_fails_with_one_line(tmp_path):
    killed = tmp_path / "killed.h5"
    subprocess.run([sys.executable, "-c", KILLED_WRITER, str(killed)], cwd=REPO)
    with SessionReader(killed) as s:
        assert not s.closed_cleanly and s.n_frames == 60
    cut = tmp_path / "cut.h5"
    cut.write_bytes(killed.read_bytes()[: killed.stat().st_size // 2])
    out = tmp_path / "recovered.h5"
    code, _, err = run_vbfe("inspect", str(cut), "--recover", str(out))
    assert code == 2 and error_lines(err) == err.strip().splitlines()
    assert f"{cut} is truncated" in err
    assert not out.exists() and not list(tmp_path.glob("*.partial"))


def test_a_changed_byte_range_in_a_frame_is_reported_by_name(tmp_path):
    path = tmp_path / "s.h5"
    write_bar_session(path, seconds=1.0)
    with h5py.File(path, "r") as f:
        info = f["camera/left"].id.get_chunk_info_by_coord((5, 0, 0, 0))
    start, n = info.byte_offset + info.size // 4, min(4096, info.size // 2)
    with open(path, "r+b") as fh:
        fh.seek(start)
        flipped = bytes(b ^ 0xFF for b in fh.read(n))
        fh.seek(start)
        fh.write(flipped)
    code, out, _ = run_vbfe("inspect", str(path), "--verify")
    assert code == 1
    damaged = [line for line in out.splitlines() if line.startswith("damaged")]
    assert damaged == [damaged[0]] and "camera/left: frame 5 " in damaged[0]
    assert "1 damaged" in out
    with SessionReader(path) as s:
        s.frame(4), s.frame(6)
        with pytest.raises(SessionError, match=r"frame 5 of .*s\.h5 is damaged.*camera/left"):
            s.frame(5)


# -- signals ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "signals, reason",
    [
        ((signal.SIGINT, signal.SIGINT), "stopped by operator"),
        ((signal.SIGTERM,), "stopped by SIGTERM"),
    ],
)
def test_ctrl_c_twice_and_sigterm_stop_and_finalize(tmp_path, signals, reason):
    path = tmp_path / "s.h5"
    proc = vbfe("record", str(path), "--config", rig(tmp_path, SMALL_BENCH))
    _wait_for_frames(path, proc)
    for sig in signals:
        proc.send_signal(sig)
        time.sleep(0.05)
    _, err = proc.communicate(timeout=60)
    # A second signal may land while the file is finishing or after it is closed (a small
    # bench finishes in under 50 ms): either way the exit status is the recording's.
    assert proc.returncode == 0, err
    with SessionReader(path) as s:
        assert s.complete and s.attrs["end_reason"] == reason and s.n_frames > 0


def test_a_second_ctrl_c_while_stopping_is_ignored_with_a_message(tmp_path, capsys):
    config = load_rig(rig(tmp_path, SMALL_BENCH))
    path = tmp_path / "s.h5"
    recorder = session_recorder(config, path, open_rig(config))
    sent: list[int] = []

    def ctrl_c_twice(rec: Recorder, stats: AcquisitionStats) -> None:
        if stats.frames > 0 and not sent:
            for _ in range(2):  # the handler runs in between: the second finds it stopping
                sent.append(os.getpid())
                os.kill(os.getpid(), signal.SIGINT)

    before = signal.getsignal(signal.SIGINT)  # SIG_IGN when started as a background job
    recorder.start()
    stats = recorder.run(None, on_tick=ctrl_c_twice)
    assert stats.end_reason == "stopped by operator" and len(sent) == 2
    assert "please wait" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGINT) is before  # put back
    with SessionReader(path) as s:
        assert s.complete and s.attrs["end_reason"] == "stopped by operator"


# -- pacing, SIGKILL loss, live view, HDMI projector ---------------------------------------------
@pytest.mark.slow
def test_live_view_runs_while_a_paced_bench_records_twenty_seconds_without_drops(tmp_path):
    live = vbfe(
        "view",
        "--live",
        "--config",
        rig(tmp_path, SMALL_BENCH + "fps = 10.0\nrealtime = true\n", "live.toml"),
    )
    try:
        started = time.monotonic()
        path = tmp_path / "paced.h5"
        config = rig(tmp_path, SMALL_BENCH + "fps = 10.0\n[record]\nqueue_size = 2\nqueue_mb = 0\n")
        code, out, err = run_vbfe(
            "record", str(path), "--duration", "20", "--config", config, timeout=400
        )
        assert code == 0, err
        with SessionReader(path) as s:
            # 20 s of 10 fps frames: the 201st lies on the boundary (the camera clock drifts)
            assert s.n_frames in (200, 201) and s.attrs["camera_queue_dropped"] == 0
            np.testing.assert_array_equal(s.stream_times("camera")[2], np.arange(s.n_frames))
            assert s.attrs["force_queue_dropped"] == 0
        summary = inspect_session(path).text()
        assert f"{s.n_frames} frames" in summary and summary.count("dropped 0 (0.00%)") == 2
        time.sleep(max(0.0, 20 - (time.monotonic() - started)))
        assert live.poll() is None, live.communicate()[1]
        live.send_signal(signal.SIGINT)
        _, err = live.communicate(timeout=30)
        assert live.returncode == 0 and "Fatal" not in err, err
    finally:  # a failed check must not leave the viewer running
        if live.poll() is None:
            live.kill()
            live.wait()


@pytest.mark.slow
def test_sigkill_loses_at_most_one_flush_interval(tmp_path):
    """Ten real-time recordings, with a 1 kHz LSL robot stream, killed at random moments; the
    next one starts while the previous one records, so start-up costs overlap."""
    from tests.fakes.lsl_outlets import FakeRobot, unique

    rng = np.random.default_rng(20)
    robot = FakeRobot(unique("robot")).start()
    config = rig(
        tmp_path,
        SMALL_BENCH + "fps = 15.0\nrealtime = true\n"
        "[record]\nflush_interval_s = 1.0\n"
        f'[streams.robot]\nname = "{robot.name}"\n',
    )
    delays = rng.uniform(0.5, 3.0, 10)
    paths = [tmp_path / f"k{k}.h5" for k in range(10)]
    procs = [vbfe("record", str(paths[0]), "--config", config)]
    losses, robot_losses = [], []
    for k, delay in enumerate(delays):
        if k + 1 < len(paths):
            procs.append(vbfe("record", str(paths[k + 1]), "--config", config))
        _wait_for_frames(paths[k], procs[k])
        time.sleep(delay)
        t_kill = time.monotonic_ns()
        procs[k].kill()
        procs[k].communicate()
        with SessionReader(paths[k]) as s:
            assert not s.closed_cleanly
            last = max(s.stream_times("camera")[1][-1], s.stream_times("force")[1][-1])
            robot_last = s.stream_times("robot")[1][-1]
        losses.append((t_kill - last) / 1e9)
        robot_losses.append((t_kill - robot_last) / 1e9)
    robot.stop()
    print(
        "SIGKILL loss (s):",
        " ".join(f"{x:.3f}" for x in sorted(losses)),
        "robot:",
        " ".join(f"{x:.3f}" for x in sorted(robot_losses)),
    )
    assert 0 <= min(losses) and max(losses) <= 1.0, losses
    assert 0 <= min(robot_losses) and max(robot_losses) <= 1.0, robot_losses


def test_hdmi_projector_records(tmp_path):
    path = tmp_path / "hdmi.h5"
    config = rig(tmp_path, SMALL_BENCH + '[projector]\nbackend = "hdmi"\nscreen = 0\n')
    code, _, err = run_vbfe("record", str(path), "--duration", "1", "--config", config)
    assert code == 0, err
    with SessionReader(path) as s:
        projector = s.metadata["devices"]["projector"]
        assert projector["kind"] == "HdmiProjector" and projector["width"] > 0
        assert [e.pattern for e in s.projector_events()] == ["debruijn-hsv"]
        assert s.complete and s.n_frames == 30
