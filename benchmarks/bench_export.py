"""MCAP export of a bench session against the time to read it.

Records a session on the simulated bench (default 20 s of 640×360 at 30 fps, lzf), then in the
same run times reading every frame and force sample through ``SessionReader`` and exporting it
with ``vbfe export`` (zstd and lz4 chunks), and prints each time with its ratio to the read
(goal: export ≤ 2× read) and the machine load. Run:
``python benchmarks/bench_export.py [--seconds S] [--width W --height H] [--repeats N]``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from functools import partial
from pathlib import Path

from vbfe.acquire import SessionReader, record_session
from vbfe.bags.export import export_mcap
from vbfe.common.config import load_config
from vbfe.truth import calibration_from_rig, true_rig


def read_all(path: Path) -> int:
    """Read every frame, force sample and timestamp the export reads; returns bytes read."""
    total = 0
    with SessionReader(path) as reader:
        total += reader.frame_times_ns().nbytes + reader.force_times_ns().nbytes
        total += reader.forces_n().nbytes
        for frame in reader.iter_frames():
            total += frame.left.nbytes + frame.right.nbytes
    return total


def best_of(repeats: int, run) -> tuple[float, float]:
    """Shortest wall time and CPU time (all threads) of ``repeats`` runs (the least disturbed
    by other load)."""
    times = []
    for _ in range(repeats):
        start, cpu = time.perf_counter(), time.process_time()
        run()
        times.append((time.perf_counter() - start, time.process_time() - cpu))
    return min(t[0] for t in times), min(t[1] for t in times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=360)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / "session.h5"
        config = load_config()
        config["bench"].update(width=args.width, height=args.height)
        start = time.perf_counter()
        record_session(
            config,
            session,
            duration_s=args.seconds,
            calibration_yaml=calibration_from_rig(true_rig(config)).to_yaml_text(),
        )
        print(
            f"recorded {args.seconds:g} s of {args.width}x{args.height} in "
            f"{time.perf_counter() - start:.1f} s: {session.stat().st_size / 1e6:.0f} MB"
        )
        nbytes = read_all(session)  # warm the page cache before timing
        read_s, read_cpu = best_of(args.repeats, lambda: read_all(session))
        print(
            f"read        wall {read_s:6.2f} s  cpu {read_cpu:6.2f} s  "
            f"({nbytes / 1e6 / read_s:.0f} MB/s decoded)"
        )
        for compression in ("zstd", "lz4"):
            out = Path(tmp) / f"session.{compression}.mcap"
            export_s, export_cpu = best_of(
                args.repeats, partial(export_mcap, session, out, None, compression)
            )
            print(
                f"export {compression:<4} wall {export_s:6.2f} s  cpu {export_cpu:6.2f} s  "
                f"({out.stat().st_size / 1e6:.0f} MB): wall {export_s / read_s:.2f}x read "
                f"(goal <= 2x), cpu {export_cpu / read_cpu:.2f}x"
            )
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
