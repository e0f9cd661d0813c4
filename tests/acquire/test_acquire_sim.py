"""Recording the simulated bench through the rig config and the `vbfe` commands."""

from __future__ import annotations

import numpy as np
import pytest

from vbfe.acquire import SessionReader, record_session
from vbfe.acquire.sync.check import verify_sync
from vbfe.acquire.sync.pullhold import METHOD as PULL_HOLD
from vbfe.cli.main import main
from vbfe.rig_config import load_rig

RIG = """
[bench]
width = 320
height = 180
stiffness_n_per_m = 200.0
pull_speed_m_per_s = 0.01
[record]
min_free_gb = 0.0
"""


@pytest.fixture(scope="module")
def sim_session(tmp_path_factory):
    """A 3 s session of the default simulated bench (small frames): rest, pull (2 N/s), hold."""
    folder = tmp_path_factory.mktemp("sim")
    rig = folder / "rig.toml"
    rig.write_text(RIG)
    path = folder / "sim.h5"
    stats = record_session(
        load_rig(rig), path, 3.0, operator="bench", notes="sim", conditions={"grasp": "2"}
    )
    return path, stats


def test_sim_session_holds_truth_conditions_and_bench(sim_session):
    path, stats = sim_session
    with SessionReader(path) as s:
        assert s.complete and s.n_frames == stats.frames >= 90
        meta = s.metadata
        assert (
            meta["conditions"]["stiffness_n_per_m"] == 200.0 and meta["conditions"]["grasp"] == "2"
        )
        assert meta["bench"]["width"] == 320
        assert [e.pattern for e in s.projector_events()] == ["debruijn-hsv"]
        truth = s.truth("force_n")
        assert truth.shape == (s.n_frames, 3)
        assert s.truth("image_minus_force_host_offset_ns")[0] == 37_000_000
        # force at frames, once the 37 ms latency difference is taken out, is the true force
        t_frames = s.frame_times_ns() - 37_000_000
        t_force, forces = s.force_times_ns(), s.forces_n()
        measured = np.interp(t_frames, t_force, forces[:, 2])
        inside = (t_frames > t_force[0]) & (t_frames < t_force[-1])
        assert np.abs(measured[inside] - truth[inside, 2]).max() < 0.15  # 0.03 N noise, quantized
        assert np.isfinite(s.force_at_frames()[1:-2]).all()


def test_verify_sync_recovers_the_bench_latency_difference(sim_session):
    path, _ = sim_session
    png = path.with_suffix(".png")
    report = verify_sync(path, store=False, plot_path=png)
    assert png.stat().st_size > 5000
    e = report.estimate  # one pull from rest to a hold: both whole records are fitted
    assert e.method == PULL_HOLD
    assert e.offset_s == pytest.approx(0.037, abs=0.005)
    assert e.ci95_s[0] <= 0.037 <= e.ci95_s[1]
    assert report.drift_ppm["force"] == pytest.approx(-60.0, abs=30)  # 3000 samples, 0.2 ms jitter


def test_cli_record_inspect_verify(tmp_path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    out = tmp_path / "cli.h5"
    assert (
        main(
            [
                "record",
                str(out),
                "--duration",
                "0.4",
                "--config",
                str(rig),
                "--operator",
                "ana",
                "--condition",
                "speed=0.01",
                "--compression",
                "blosc-lz4",
            ]
        )
        == 0
    )
    assert "frames" in capsys.readouterr().out
    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert "complete (duration reached)" in text and "operator ana" in text
    assert "drift" in text and "blosc-lz4" in text
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"nope" * 50)
    assert main(["inspect", str(junk)]) == 2
    assert "junk.h5 is not a readable HDF5 file" in capsys.readouterr().err
    assert main(["record", str(out), "--config", str(rig)]) == 2
    assert "already exists" in capsys.readouterr().err
