"""verify-sync accuracy on the simulated bench: offset and clock drift against the bench's truth.

Records one session per (paper condition, seed) through ``record_session`` with the default
``[bench]`` table (size, rate and hold overridable), runs :func:`verify_sync` and prints, per
session, the measured image−force offset against the true one (difference of the median
latencies, 37 ms by default), whether the 95% interval holds the truth, and the camera/trocar
drift estimates (± standard error) against the bench's; then the spread of the errors. Time is
reported as a ratio: verify-sync time over the time to read the session's frames once.

    python benchmarks/bench_sync.py [--width 640 --height 360 --fps 30 --hold 3 --seeds 2]
"""

from __future__ import annotations

import argparse
import copy
import tempfile
import time
from pathlib import Path

import numpy as np

from vbfe.acquire import SessionReader, record_session
from vbfe.acquire.sync_check import verify_sync
from vbfe.config import load_config
from vbfe.drivers.sim import SimBench
from vbfe.drivers.sim.mechanics import PAPER_CONDITIONS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=360)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--hold", type=float, default=3.0, help="hold after the pull (s)")
    parser.add_argument("--seeds", type=int, default=2, help="sessions per paper condition")
    args = parser.parse_args()
    config = load_config(None)
    config["bench"].update(width=args.width, height=args.height, fps=args.fps, hold_s=args.hold)
    config["record"]["min_free_gb"] = 0.0
    errors, covered, drift_errors = [], [], []
    with tempfile.TemporaryDirectory() as folder:
        for n, (stiffness, speed) in enumerate(
                [(k, v) for k, v in PAPER_CONDITIONS.items() for _ in range(args.seeds)]):
            run = copy.deepcopy(config)
            run["bench"].update(stiffness_n_per_m=stiffness, pull_speed_m_per_s=speed, seed=n + 1)
            bench = SimBench.from_config(run["bench"])
            path = Path(folder) / f"s{n}.h5"
            record_session(run, path, duration_s=bench.duration_s())
            start = time.perf_counter()
            with SessionReader(path) as reader:
                for _ in reader.iter_frames():
                    pass
                true_s = float(np.median(reader.truth("image_minus_force_host_offset_ns"))) / 1e9
            read_s = time.perf_counter() - start
            start = time.perf_counter()
            report = verify_sync(path, store=False)
            verify_s = time.perf_counter() - start
            e = report.estimate
            errors.append(e.offset_s - true_s)
            covered.append(e.ci95_s[0] <= true_s <= e.ci95_s[1])
            truth_ppm = {"camera": bench.camera_clock.drift_ppm,
                         "force": bench.trocar_clock.drift_ppm}
            drifts = "  ".join(f"{s} {report.drift_ppm[s]:+6.1f}"
                               f"±{report.drift_uncertainty_ppm[s]:.1f} (true {truth_ppm[s]:+.0f})"
                               for s in truth_ppm)
            drift_errors.append(report.drift_ppm["camera"] - truth_ppm["camera"])
            print(f"k={stiffness:g} v={speed:g} seed {n + 1}: {bench.duration_s():.1f} s, "
                  f"offset {1e3 * e.offset_s:6.2f} ms (true {1e3 * true_s:.2f}, error "
                  f"{1e3 * errors[-1]:+5.2f}, 95% CI {1e3 * e.ci95_s[0]:.1f}…"
                  f"{1e3 * e.ci95_s[1]:.1f}{' holds' if covered[-1] else ' MISSES'} the truth; "
                  f"{e.method}); {drifts}; "
                  f"verify/read time {verify_s / read_s:.2f}")
    err = 1e3 * np.abs(errors)
    print(f"offset |error|: median {np.median(err):.2f} ms, max {err.max():.2f} ms, within ±5 ms "
          f"{np.mean(err <= 5):.0%}, within ±3 ms {np.mean(err <= 3):.0%}; 95% CI holds the "
          f"truth in {np.mean(covered):.0%}; camera drift |error| max "
          f"{np.max(np.abs(drift_errors)):.1f} ppm")


if __name__ == "__main__":
    main()
