"""Recording through the real V4L2 and CAN drivers, driven by the shared fakes."""

from __future__ import annotations

import json
import re

import numpy as np

from tests.acquire.test_acquire_devices import RecordingProjector, force_profile
from tests.cli import vbfe_here
from tests.fakes.camera import FakeStereoCamera, frame_seq
from tests.fakes.trocar import FakeTrocar
from vbfe.acquire import Recorder, SessionReader
from vbfe.drivers.rig import Rig


def test_v4l2_camera_vanishing_ends_session_with_gap_and_can_forces(tmp_path):
    path = tmp_path / "s.h5"
    with FakeTrocar("acquire-test", force_profile, rate_hz=500.0, noise_n=0.01) as fake:
        devices = Rig(
            FakeStereoCamera(disconnect_after=25, drop_seqs=(7, 8)),
            fake.trocar(),
            RecordingProjector(),
        )
        with Recorder(
            devices, path, compression="lzf", flush_interval_s=0.2, min_free_bytes=0
        ) as rec:
            stats = rec.run(10.0)
    assert "camera disconnected" in stats.end_reason
    with SessionReader(path) as s:
        assert s.complete
        seqs = s.stream_times("camera")[2]
        assert 7 not in seqs and 8 not in seqs
        for i in range(s.n_frames):
            assert frame_seq(s.frame(i).left) == seqs[i]
        assert [g["reason"] for g in s.gaps() if g["stream"] == "camera"] == ["device disconnected"]
        forces = s.forces_n()
        assert len(forces) > 100
        force_seqs = s.stream_times("force")[2]
        expected = np.array([fake.sent_forces_n[int(n)] for n in force_seqs])
        np.testing.assert_allclose(forces, expected, atol=0.02)  # trocar resolution
        # every frame inside the force record has a force (the trocar's bus may connect a few
        # frames after the camera started on a loaded machine)
        t_frames, t_force = s.frame_times_ns(), s.force_times_ns()
        inside = (t_frames > t_force.min()) & (t_frames < t_force.max())
        assert inside.sum() >= 15
        assert np.isfinite(s.force_at_frames()[inside]).all()
        # the trocar's clock: undecided at the start, the sender's stamps once frames came
        at_start = s.metadata["devices"]["trocar"]["device_clock"]
        at_end = json.loads(s.attrs["devices_at_end_json"])["trocar"]["device_clock"]
        assert at_start.startswith("interface timestamp if the first frame carries one")
        assert at_end.startswith("the sender's time.time()")
        # the session keeps the recording's log: devices opened and closed, the gap, the
        # drops and the clock fits
        log = "\n".join(s.log())
    for words in ("opened", "closed", "camera gap (device disconnected)", "2 records dropped"):
        assert words in log, (words, log)
    assert "force clock fit:" in log and "camera clock fit:" in log


def test_record_log_file_holds_device_and_drop_events(tmp_path, capsys):
    """`vbfe record --log-file L` (the real CLI, a simulated camera, the CAN trocar on a
    virtual bus that loses every 25th sample): the device and drop events reach L."""
    rig = tmp_path / "rig.toml"
    rig.write_text(
        "[bench]\nwidth = 160\nheight = 120\n[record]\nmin_free_gb = 0.0\n"
        '[trocar]\nbackend = "can"\ninterface = "virtual"\nchannel = "log-file-test"\n'
    )
    log_file = tmp_path / "record.log"
    with FakeTrocar(
        "log-file-test", force_profile, rate_hz=500.0, drop_counters=range(0, 10**6, 25)
    ):
        done = vbfe_here(
            capsys,
            "record",
            str(tmp_path / "s.h5"),
            "--duration",
            "0.5",
            "--config",
            str(rig),
            "--log-file",
            str(log_file),
        )
    assert done.returncode == 0, done.err
    log = log_file.read_text()
    for words in ("trocar on CAN virtual channel", "opened", "closed", "force: "):
        assert words in log, (words, log)
    dropped = re.search(r"force: (\d+) records dropped \(0 by the queue", log)
    assert dropped and int(dropped[1]) >= 2, log
    with SessionReader(tmp_path / "s.h5") as s:
        assert dropped[0] in "\n".join(s.log())
        assert int(dropped[1]) == s.attrs["force_device_dropped"]
