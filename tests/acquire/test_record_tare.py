"""`vbfe record --tare`: the unloaded trocar is zeroed from its first N samples."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from vbfe.acquire import SessionReader

RIG = """
[bench]
width = 320
height = 180
force_noise_n = 0.02
[record]
min_free_gb = 0.0
tare_samples = 300
"""


def test_record_tare_zeroes_the_trocar_and_stores_the_offset(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    out = tmp_path / "tared.h5"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "vbfe.cli.main",
            "record",
            str(out),
            "--duration",
            "0.3",
            "--tare",
            "--config",
            str(rig),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    with SessionReader(out) as session:
        meta = session.metadata
        forces = session.forces_n()
    tare = meta["tare"]
    assert tare["samples"] == 300 and len(tare["offset_n"]) == 3
    assert meta["devices"]["trocar"]["offset_n"] == tare["offset_n"]
    # at rest the raw samples are noise about zero: the mean of 300 is within 5 sigma/sqrt(300)
    assert np.all(np.abs(tare["offset_n"]) < 5 * 0.02 / np.sqrt(300))
    assert np.any(np.array(tare["offset_n"]) != 0.0)
    # the sensor quantizes to its resolution: raw samples sit on that grid, so the recorded
    # samples plus the offset do, and the recorded ones themselves do not
    resolution = meta["devices"]["trocar"]["resolution_n"]
    raw_steps = (forces + np.array(tare["offset_n"])) / resolution
    assert np.abs(raw_steps - np.round(raw_steps)).max() < 1e-6
    steps = forces / resolution
    assert np.abs(steps - np.round(steps)).max() > 0.01
