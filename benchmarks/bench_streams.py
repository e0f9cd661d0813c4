"""The lab's other streams on this machine: recording a 1 kHz robot stream and a marker stream
beside the bench (loss, agreement with the host clock) and the live estimate's latency as an
LSL consumer sees it.

1. ``vbfe record`` of the bench (320x180, 10 fps, real time) with a fake robot outlet at 1 kHz
   and a marker outlet, on loopback: robot samples lost, the largest difference between a
   recorded host time and the time the robot stamped, marker times likewise.
2. ``vbfe live --lsl --headless`` (a tiny model trained here) consumed by a pylsl inlet: latency
   from frame capture (the sample's stamp) to receipt (``local_clock()``), p50/p95, against the
   estimator's own capture→estimate latency (the ``latency_s`` channel) measured in the same
   run: their ratio and difference are what LSL delivery adds.

Run: ``python -m benchmarks.bench_streams [--seconds 10]``; prints the load average too.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pylsl

from benchmarks import smoke
from tests.fakes.lsl_outlets import FakeRobot, MarkerOutlet, unique
from vbfe.acquire import SessionReader
from vbfe.rig_config import builtin_rig

BENCH = {"width": 320, "height": 180, "fps": 10.0, "distortion": False, "realtime": True, "seed": 3}


def _toml(extra: str = "") -> str:
    return (
        "[bench]\n"
        + "".join(
            f"{k} = {str(v).lower() if isinstance(v, bool) else v}\n" for k, v in BENCH.items()
        )
        + extra
    )


def _vbfe(*args: object) -> list[str]:
    return [sys.executable, "-m", "vbfe.cli.main", *map(str, args)]


def bench_record(folder: Path, seconds: float) -> None:
    robot, marks = FakeRobot(unique("robot")), MarkerOutlet(unique("script"))
    toml = folder / "rig.toml"
    toml.write_text(
        _toml(f'[streams.robot]\nname = "{robot.name}"\n[streams.script]\nname = "{marks.name}"\n')
    )
    path = folder / "s.h5"
    with robot:
        proc = subprocess.Popen(
            _vbfe("record", path, "--duration", seconds, "--config", toml),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        marks.outlet.wait_for_consumers(60.0)
        while proc.poll() is None:
            marks.mark(f"marker {len(marks.sent)}")
            time.sleep(0.5)
        if proc.returncode:
            raise SystemExit(proc.stderr.read())
    with SessionReader(path) as reader:
        stream, events = reader.stream("robot"), reader.events()
        camera_seq = reader.stream_times("camera")[2]
    due = robot.due_times_ns()
    index = np.clip(np.searchsorted(due, stream.t_host_ns - 500_000), 0, len(due) - 1)
    expected = index[-1] - index[0] + 1  # pushed between the first and last recorded sample
    recorded = {e["text"]: e["t_host_ns"] for e in events}
    window = [
        (t, text) for t, text in marks.sent if stream.t_host_ns[0] <= t <= stream.t_host_ns[-1]
    ]
    marker_diff = [abs(recorded[text] - t) for t, text in window if text in recorded]
    print(
        f"record {seconds:g} s: robot {len(np.unique(index))} of {expected} samples "
        f"(loss {100 * (1 - len(np.unique(index)) / expected):.3f} %), host-clock agreement "
        f"max {np.max(np.abs(stream.t_host_ns - due[index])) / 1e6:.3f} ms; markers sent "
        f"while recording {len(marker_diff)} of {len(window)}, max "
        f"{max(marker_diff, default=0) / 1e6:.3f} ms; frames {len(camera_seq)} of "
        f"{camera_seq[-1] - camera_seq[0] + 1}"
    )


def _model(folder: Path) -> tuple[Path, Path]:
    from vbfe.estimate.synthetic import synthetic_sessions
    from vbfe.estimate.train_config import TrainConfig
    from vbfe.estimate.training import train
    from vbfe.truth import calibration_from_rig, true_rig

    model = folder / "model.pt"
    train(
        synthetic_sessions(repeats=1, seed=1, fps=4, points_per_side=20),
        model,
        TrainConfig(
            epochs=4,
            batch_size=16,
            n_points=64,
            conv_channels=[16, 32, 64],
            head_channels=[32],
            val_fraction=1 / 3,
            seed=0,
            threads=1,
        ),
    )
    config = builtin_rig({"bench": dict(BENCH)})
    return model, calibration_from_rig(true_rig(config)).save(folder / "calib.yaml")


def bench_live(folder: Path, seconds: float) -> None:
    model, calib = _model(folder)
    toml = folder / "live.toml"
    toml.write_text(_toml())
    source = unique("vbfe-bench")
    proc = subprocess.Popen(
        _vbfe(
            "live",
            "--model",
            model,
            "--calib",
            calib,
            "--headless",
            "--duration",
            seconds + 5,
            "--lsl",
            source,
            "--config",
            toml,
        ),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    found = pylsl.resolve_bypred(f"source_id='{source}-estimate'", timeout=60.0)
    if not found:
        raise SystemExit(f"no vbfe-estimate outlet appeared: {proc.stderr.read()}")
    inlet = pylsl.StreamInlet(found[0])
    inlet.open_stream(timeout=10.0)
    end_to_end, estimator = [], []
    until = time.monotonic() + seconds
    while time.monotonic() < until:
        sample, stamp = inlet.pull_sample(timeout=1.0)
        if sample is not None:
            end_to_end.append(pylsl.local_clock() - stamp)
            estimator.append(sample[-1])
    proc.wait(timeout=120)
    e2e, est = np.array(end_to_end) * 1e3, np.array(estimator) * 1e3
    p95, est_p95 = np.percentile(e2e, 95), np.percentile(est, 95)
    print(
        f"live --lsl {seconds:g} s: {len(e2e)} estimates received; capture -> receipt p50 "
        f"{np.percentile(e2e, 50):.1f} ms, p95 {p95:.1f} ms; capture -> estimate p95 "
        f"{est_p95:.1f} ms (ratio {p95 / est_p95:.3f}); LSL delivery p95 "
        f"{np.percentile(e2e - est, 95):.2f} ms"
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    args = smoke.parse(parser, argv, seconds=1.0)
    print(
        f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} on {os.cpu_count()} cores"
    )
    with tempfile.TemporaryDirectory() as tmp:
        bench_record(Path(tmp), args.seconds)
        bench_live(Path(tmp), args.seconds)
    print(f"load average {os.getloadavg()[0]:.2f} after")


if __name__ == "__main__":
    main()
