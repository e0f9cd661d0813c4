"""Two recordings of one simulated-bench config hold the same frames and forces, bit for bit."""

from __future__ import annotations

import time

import h5py
import numpy as np

from vbfe.acquire import Recorder, SessionReader
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.registry import open_rig
from vbfe.rig_config import RigConfig, load_rig

RIG = """
[bench]
width = 320
height = 180
fps = 20.0
seed = 7
stiffness_n_per_m = 200.0
pull_speed_m_per_s = 0.01
rest_s = 0.2
[record]
min_free_gb = 0.0
"""


def _record(config: RigConfig, path, slow_writer: bool) -> None:
    """Record 1.2 s; ``slow_writer`` stalls the writer at every flush to shift thread timing."""
    devices = open_rig(config)
    stall = (lambda stats: time.sleep(0.15)) if slow_writer else None
    projector = devices.projector
    recorder = Recorder(
        devices,
        path,
        flush_interval_s=0.05 if slow_writer else 1.0,
        min_free_bytes=0,
        on_flush=stall,
        pattern=make_pattern(projector.width, projector.height),
    )
    recorder.start()
    recorder.run(1.2)


def _datasets(path) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    with h5py.File(path, "r") as f:
        for group in ("camera", "force"):
            f[group].visititems(
                lambda name, obj, group=group: (
                    out.__setitem__(f"{group}/{name}", obj[()].tobytes())
                    if isinstance(obj, h5py.Dataset)
                    else None
                )
            )
    return out


def test_two_recordings_of_one_bench_config_are_bit_identical(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    config = load_rig(rig)
    first, second = tmp_path / "a.h5", tmp_path / "b.h5"
    _record(config, first, slow_writer=False)
    _record(config, second, slow_writer=True)
    with SessionReader(first) as a, SessionReader(second) as b:
        assert a.n_frames == b.n_frames == 24  # 1.2 s at 20 fps
        assert len(a.forces_n()) == len(b.forces_n()) > 1100  # 1 kHz up to the last frame's end
        np.testing.assert_array_equal(a.forces_n(), b.forces_n())
        for stream in ("camera", "force"):
            for x, y in zip(a.stream_times(stream), b.stream_times(stream), strict=False):
                np.testing.assert_array_equal(x, y)
        for i in (0, a.n_frames - 1):
            np.testing.assert_array_equal(a.frame(i).left, b.frame(i).left)
        assert np.ptp(a.forces_n()[:, 2]) > 0.5  # the pull is in the recording
    raw_a, raw_b = _datasets(first), _datasets(second)
    assert raw_a.keys() == raw_b.keys() and len(raw_a) >= 6
    for name in raw_a:
        assert raw_a[name] == raw_b[name], name
