"""A recorder killed mid-recording leaves a readable file with everything it had flushed."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from tests.paths import REPO
from vbfe.acquire import SessionError, SessionReader, store_calibration
from vbfe.acquire.session.inspect import inspect_session
from vbfe.cli.main import main

RECORDER_SCRIPT = textwrap.dedent("""
    import json, sys
    import numpy as np
    from tests.acquire.test_acquire_devices import bar_devices
    from vbfe.acquire import Recorder

    def report(stats):
        print(json.dumps(stats.flushed), flush=True)

    rec = Recorder(bar_devices(speed=2.0, width=160, height=120), sys.argv[1],
                   compression="blosc-lz4", flush_interval_s=0.2, min_free_bytes=0,
                   pattern=np.zeros((48, 64, 3), np.uint8), pattern_name="debruijn",
                   on_flush=report)
    rec.start()
    rec.run(60.0)
""")


def test_sigkill_mid_recording_keeps_everything_up_to_the_last_flush(tmp_path, capsys):
    path = tmp_path / "killed.h5"
    proc = subprocess.Popen(
        [sys.executable, "-c", RECORDER_SCRIPT, str(path)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    flushed = []
    deadline = time.monotonic() + 60
    while len(flushed) < 6 and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        flushed.append(json.loads(line))
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert len(flushed) == 6, "the recorder subprocess did not report its flushes"
    last = flushed[-1]
    assert last["camera"] > 0 and last["force"] > 0

    with SessionReader(path) as s:
        assert not s.closed_cleanly and not s.complete
        assert s.n_frames >= last["camera"]
        assert len(s.forces_n()) >= last["force"]
        seqs = s.stream_times("camera")[2]
        np.testing.assert_array_equal(seqs, np.arange(s.n_frames))
        for i in range(s.n_frames):
            assert s.frame(i).left[0, 0, 0] == i % 256
        assert [e.pattern for e in s.projector_events()] == ["debruijn"]
        assert np.isfinite(s.force_at_frames()[1:-1]).all()

    report = inspect_session(path)
    assert report.truncated
    assert "not closed cleanly" in report.text().lower()
    with pytest.raises(SessionError, match="killed.h5 was not closed cleanly.*--recover"):
        store_calibration(path, "%YAML:1.0\n")

    fixed = tmp_path / "fixed.h5"
    assert main(["inspect", str(path), "--recover", str(fixed)]) == 0
    assert "recovered: the recording was interrupted" in capsys.readouterr().out
    store_calibration(fixed, "%YAML:1.0\n")
    with SessionReader(fixed) as s:
        assert s.complete and s.n_frames >= last["camera"]
        assert s.clock_fit("camera").n_pairs == s.n_frames
        assert s.calibration_yaml() == "%YAML:1.0\n"
