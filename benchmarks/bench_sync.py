"""verify-sync accuracy on the simulated bench: offset and clock drift against the bench's truth.

By default: sync protocol sessions (taps and projector flashes) with 5, 10, 20 and 40 events of
each kind (``--seeds`` sessions each, 320×180 at 30 fps, true offset 37 ms): per number of
events, the offset's error and 95% half-width and the flash latency's, so an operator knows how
many taps are enough. Analysis time is a ratio: verify-sync over reading the frames once.

    python -m benchmarks.bench_sync [--events 5 10 20 40 --seeds 3]

With ``--protocols``: per protocol, the passive offset's error, 95% half-width and coverage:
``--freehand`` textured freehand trials (20) and ``--seeds`` pull-hold sessions per paper
condition (6: the demo's 18), recorded as the demo records them (seeds, texture).

    python -m benchmarks.bench_sync --protocols [--width 640 --height 360 --fps 10]

With ``--passive``: records one traction session per (paper condition, seed) through
``record_session`` with the default ``[bench]`` table (size, rate and hold overridable), runs
:func:`verify_sync` and prints, per session, the measured image−force offset against the true
one (difference of the median latencies, 37 ms by default), whether the 95% interval holds the
truth, and the camera/trocar drift estimates (± standard error) against the bench's; then the
spread of the errors. Time is reported as a ratio: verify-sync time over the time to read the
session's frames once.

    python -m benchmarks.bench_sync --passive [--width 640 --height 360 --fps 30 --hold 3 --seeds 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import smoke
from vbfe.acquire import SessionReader, record_session
from vbfe.acquire.recording.sync_session import SyncProtocol
from vbfe.acquire.sync.check import verify_sync
from vbfe.acquire.sync.protocol import ProtocolSettings
from vbfe.drivers.sim import SimBench
from vbfe.drivers.sim.mechanics import PAPER_CONDITIONS
from vbfe.rig_config import builtin_rig
from vbfe.truth import trial_duration_s


def _read_time(path: Path) -> float:
    start = time.perf_counter()
    with SessionReader(path) as reader:
        for _ in reader.iter_frames():
            pass
    return time.perf_counter() - start


def protocol_sweep(events: list[int], seeds: int) -> None:
    """Error and 95% half-width of the tap offset and flash latency against the event count."""
    config = builtin_rig(
        {
            "bench": dict(width=320, height=180, fps=30.0, distortion=False),
            "record": {"min_free_gb": 0.0},
        }
    )
    settings = ProtocolSettings.from_record(config.record)
    true_latency = 1e-3 * (
        config.tables["bench"]["image_latency_ms"] + config.tables["bench"]["projector_latency_ms"]
    )
    print(
        f"{'events':>6} {'|offset error| mean/max (ms)':>29} {'half-width (ms)':>16} "
        f"{'covers':>6} {'|flash error| mean/max (ms)':>28} {'half-width (ms)':>16} "
        f"{'verify/read':>11}"
    )
    with tempfile.TemporaryDirectory() as folder:
        for n in events:
            rows = []
            for seed in range(1, seeds + 1):
                run = config.updated({"bench": {"seed": 100 * n + seed}})
                path = Path(folder) / f"n{n}_s{seed}.h5"
                record_session(
                    run,
                    path,
                    protocol=SyncProtocol(
                        taps=n, flashes=n, duration_s=max(10.0, float(n)), seed=seed
                    ),
                )
                with SessionReader(path) as reader:
                    true_s = (
                        float(np.median(reader.truth("image_minus_force_host_offset_ns"))) / 1e9
                    )
                read_s = _read_time(path)
                start = time.perf_counter()
                report = verify_sync(path, settings=settings, store=False)
                ratio = (time.perf_counter() - start) / read_s
                e, f = report.estimate, report.protocol.flash_latency
                rows.append(
                    (
                        e.offset_s - true_s,
                        (e.ci95_s[1] - e.ci95_s[0]) / 2,
                        e.ci95_s[0] <= true_s <= e.ci95_s[1],
                        f.value_s - true_latency,
                        f.half_width_s,
                        ratio,
                    )
                )
            err, half, covers, ferr, fhalf, ratio = (np.array(c) for c in zip(*rows, strict=False))
            print(
                f"{n:>6} {1e3 * np.mean(np.abs(err)):>14.2f} / {1e3 * np.max(np.abs(err)):<12.2f}"
                f"{1e3 * np.mean(half):>16.2f} {np.mean(covers):>6.0%} "
                f"{1e3 * np.mean(np.abs(ferr)):>13.2f} / {1e3 * np.max(np.abs(ferr)):<12.2f}"
                f"{1e3 * np.mean(fhalf):>16.2f} {np.mean(ratio):>11.2f}"
            )


def passive(args: argparse.Namespace) -> None:
    """The passive estimate on traction sessions over the paper's conditions."""
    config = builtin_rig(
        {
            "bench": dict(width=args.width, height=args.height, fps=args.fps, hold_s=args.hold),
            "record": {"min_free_gb": 0.0},
        }
    )
    errors, covered, drift_errors = [], [], []
    with tempfile.TemporaryDirectory() as folder:
        for n, (stiffness, speed) in enumerate(
            [(k, v) for k, v in PAPER_CONDITIONS.items() for _ in range(args.seeds)]
        ):
            trial = dict(stiffness_n_per_m=stiffness, pull_speed_m_per_s=speed, seed=n + 1)
            run = config.updated({"bench": trial})
            bench = SimBench.from_config(run.tables["bench"])
            path = Path(folder) / f"s{n}.h5"
            record_session(run, path, duration_s=bench.duration_s())
            with SessionReader(path) as reader:
                true_s = float(np.median(reader.truth("image_minus_force_host_offset_ns"))) / 1e9
            read_s = _read_time(path)
            start = time.perf_counter()
            report = verify_sync(
                path, settings=ProtocolSettings.from_record(run.record), store=False
            )
            verify_s = time.perf_counter() - start
            e = report.estimate
            errors.append(e.offset_s - true_s)
            covered.append(e.ci95_s[0] <= true_s <= e.ci95_s[1])
            truth_ppm = {
                "camera": bench.camera_clock.drift_ppm,
                "force": bench.trocar_clock.drift_ppm,
            }
            drifts = "  ".join(
                f"{s} {report.drift_ppm[s]:+6.1f}"
                f"±{report.drift_uncertainty_ppm[s]:.1f} (true {truth_ppm[s]:+.0f})"
                for s in truth_ppm
            )
            drift_errors.append(report.drift_ppm["camera"] - truth_ppm["camera"])
            print(
                f"k={stiffness:g} v={speed:g} seed {n + 1}: {bench.duration_s():.1f} s, "
                f"offset {1e3 * e.offset_s:6.2f} ms (true {1e3 * true_s:.2f}, error "
                f"{1e3 * errors[-1]:+5.2f}, 95% CI {1e3 * e.ci95_s[0]:.1f}…"
                f"{1e3 * e.ci95_s[1]:.1f}{' holds' if covered[-1] else ' MISSES'} the truth; "
                f"{e.method}); {drifts}; "
                f"verify/read time {verify_s / read_s:.2f}"
            )
    err = 1e3 * np.abs(errors)
    print(
        f"offset |error|: median {np.median(err):.2f} ms, max {err.max():.2f} ms, within ±5 ms "
        f"{np.mean(err <= 5):.0%}, within ±3 ms {np.mean(err <= 3):.0%}; 95% CI holds the "
        f"truth in {np.mean(covered):.0%}; camera drift |error| max "
        f"{np.max(np.abs(drift_errors)):.1f} ppm"
    )


def _passive_row(path: Path, settings: ProtocolSettings) -> tuple[float, float, bool, str]:
    """verify-sync on one session (the camera's exposure from ``settings``, as ``vbfe
    verify-sync`` takes it from the rig file): error against the bench's true offset, 95%
    half-width, whether the interval holds the truth, and the method."""
    with SessionReader(path) as reader:
        true_s = float(np.median(reader.truth("image_minus_force_host_offset_ns"))) / 1e9
    e = verify_sync(path, settings=settings, store=False).estimate
    return (
        e.offset_s - true_s,
        (e.ci95_s[1] - e.ci95_s[0]) / 2,
        e.ci95_s[0] <= true_s <= e.ci95_s[1],
        e.method,
    )


def protocols(args: argparse.Namespace) -> None:
    """Per protocol (freehand trials, the paper's pull-hold sessions), the passive offset's
    error, 95% half-width and coverage, as the demo records them (textured freehand trials)."""
    config = builtin_rig(
        {
            "bench": dict(width=args.width, height=args.height, fps=args.fps, hold_s=args.hold),
            "record": {"min_free_gb": 0.0},
        }
    )
    runs = {
        "freehand": [
            {
                "protocol": "freehand",
                "freehand_duration_s": args.freehand_s,
                "textured": True,
                "seed": 101 + i,
            }
            for i in range(args.freehand)
        ],
        "pull-hold": [
            {"stiffness_n_per_m": k, "pull_speed_m_per_s": v, "seed": 1 + i}
            for i, (k, v) in enumerate(  # seeds paired with conditions as the demo pairs them
                [(k, v) for k, v in PAPER_CONDITIONS.items() for _ in range(args.seeds)]
            )
        ],
    }
    print(
        f"{'protocol':>9} {'sessions':>8} {'|error| median/max (ms)':>24} "
        f"{'half-width median/max (ms)':>27} {'covers':>7} {'verify (s)':>10}"
    )
    with tempfile.TemporaryDirectory() as folder:
        for name, benches in runs.items():
            rows, times = [], []
            for i, bench in enumerate(benches):
                run = config.updated({"bench": bench})
                path = Path(folder) / f"{name}{i}.h5"
                record_session(run, path, duration_s=trial_duration_s(run))
                start = time.perf_counter()
                rows.append(_passive_row(path, ProtocolSettings.from_record(run.record)))
                times.append(time.perf_counter() - start)
                err, half, covers, method = rows[-1]
                print(
                    f"  {name} {i}: error {1e3 * err:+.2f} ms, 95% half-width "
                    f"{1e3 * half:.2f} ms, {'holds' if covers else 'MISSES'} the truth ({method})",
                    flush=True,
                )
                path.unlink()
            if not rows:
                continue
            err, half, covers, _ = (np.array(c) for c in zip(*rows, strict=True))
            err, half = 1e3 * np.abs(err), 1e3 * half
            print(
                f"{name:>9} {len(rows):>8} {np.median(err):>11.2f} / {err.max():<10.2f}"
                f"{np.median(half):>13.2f} / {half.max():<11.2f}"
                f"{int(covers.sum()):>3}/{len(rows):<3} {np.mean(times):>10.1f}",
                flush=True,
            )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--events",
        type=int,
        nargs="+",
        default=[5, 10, 20, 40],
        help="taps and flashes per protocol session",
    )
    parser.add_argument(
        "--passive", action="store_true", help="measure traction sessions passively instead"
    )
    parser.add_argument(
        "--protocols",
        action="store_true",
        help="passive error, interval and coverage per protocol (freehand, pull-hold)",
    )
    parser.add_argument("--freehand", type=int, default=20, help="freehand trials (--protocols)")
    parser.add_argument("--freehand-s", type=float, default=15.0, help="freehand trial length")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=360)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--hold", type=float, default=3.0, help="hold after the pull (s)")
    parser.add_argument(
        "--seeds",
        type=int,
        default=None,
        help="sessions per event count (3) or per paper condition (2)",
    )
    args = smoke.parse(parser, argv, events=[5], seeds=1)
    if args.protocols:
        args.seeds = 6 if args.seeds is None else args.seeds
        protocols(args)
    elif args.passive:
        args.seeds = args.seeds or 2
        passive(args)
    else:
        protocol_sweep(args.events, args.seeds or 3)


if __name__ == "__main__":
    main()
