"""Recording with the live estimate on a busy machine: the file must lose no frame, the
estimate skips frames instead.

Records ``--seconds`` (60) at ``--size`` (640x360), 30 fps, from the OpenCV camera driver
replaying frames the bench rendered beforehand (bench_live's replay rig: a real endoscope's
frames cost the host nothing to make), as ``vbfe live --record`` does: the live run over a
recorder with the ``[record]`` settings, the demo's PointNet 32-64-256 (untrained: speed does
not depend on the weights), ``[live]``'s scale and thread counts, and ``--busy N`` processes
(``yes > /dev/null``) beside it; ``--runs`` times. Prints per run the frames the file holds
and those it lost (the writer's queue full; the camera's side), the estimates per second and
the share of frames the estimate skipped (``missing``: sequence numbers absent from the file;
``stored raw``: frames the writer, behind, stored uncompressed), and where the threads' time
went, from Linux's
per-thread schedstat: on a CPU, waiting for one (run queue), and the rest (blocked: I/O, the
GIL, waiting for work), with each group's nice value. Run: ``python -m
benchmarks.bench_live_record [--seconds 60] [--runs 3] [--busy 1] [--size 640x360]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks import smoke
from benchmarks.bench_live import FPS, REPLAY_FRAMES, rendered_frames, replay_rig, untrained_model
from vbfe.acquire import SessionReader
from vbfe.acquire.recording.record import session_recorder
from vbfe.acquire.recording.recorder import Recorder
from vbfe.acquire.session.extra_streams import marks_stream
from vbfe.acquire.session.layout import CAMERA
from vbfe.live.estimator import FrameEstimator
from vbfe.live.run import LiveRun, run_headless, use_threads
from vbfe.rig_config import RigConfig, builtin_rig
from vbfe.truth import calibration_from_rig, true_rig

GROUPS = {  # thread name prefix -> the group it is counted in
    "vbfe-read-camera": "camera reader",
    "vbfe-dispatch-live": "live dispatch",
    "vbfe-dispatch": "writer (dispatch)",
    "vbfe-live-": "estimator stages",
}
OTHER = "other (main, readers, pools)"


def schedstat(tid: int) -> tuple[int, int]:
    """Nanoseconds thread ``tid`` of this process spent on a CPU and waiting for one."""
    run_ns, wait_ns, _ = (
        int(v) for v in Path(f"/proc/self/task/{tid}/schedstat").read_text().split()
    )
    return run_ns, wait_ns


def time_the_writes(recorder: Recorder) -> list[int]:
    """Wrap the session sink's record hook: for the camera's frames, the ns it took in all,
    on a CPU and waiting for one (the rest: blocked on the GIL, a lock or I/O); returned as
    a list those sums accumulate in."""
    sums = [0, 0, 0]
    write = recorder.sink.on_records

    def timed(stream: str, records: Sequence[Any]) -> None:
        if stream != CAMERA:
            write(stream, records)
            return
        tid = threading.get_native_id()
        (run0, wait0), t0 = schedstat(tid), time.monotonic_ns()
        write(stream, records)
        (run1, wait1), t1 = schedstat(tid), time.monotonic_ns()
        sums[0] += t1 - t0
        sums[1] += run1 - run0
        sums[2] += wait1 - wait0

    recorder.sink.on_records = timed  # type: ignore[method-assign]
    return sums


def thread_times() -> dict[int, tuple[str, int, int, int]]:
    """Every thread of this process: its group, ns on a CPU, ns waiting for one, nice value."""
    names = {t.native_id: t.name for t in threading.enumerate()}
    out = {}
    for task in Path("/proc/self/task").iterdir():
        try:
            run_ns, wait_ns, _ = (int(v) for v in (task / "schedstat").read_text().split())
            nice = int((task / "stat").read_text().rsplit(")", 1)[1].split()[16])
        except (OSError, ValueError):
            continue  # the thread ended meanwhile
        name = names.get(int(task.name), "")
        group = next((g for prefix, g in GROUPS.items() if name.startswith(prefix)), OTHER)
        out[int(task.name)] = (group, run_ns, wait_ns, nice)
    return out


def time_by_group(
    first: dict[int, tuple[str, int, int, int]], last: dict[int, tuple[str, int, int, int]]
) -> dict[str, tuple[float, float, int, set[int]]]:
    """Per group: seconds on a CPU, seconds waiting for one, threads, nice values."""
    out: dict[str, tuple[float, float, int, set[int]]] = {}
    for tid, (group, run_ns, wait_ns, nice) in last.items():
        _, run0, wait0, _ = first.get(tid, (group, 0, 0, nice))
        cpu, wait, n, nices = out.get(group, (0.0, 0.0, 0, set()))
        out[group] = (cpu + (run_ns - run0) / 1e9, wait + (wait_ns - wait0) / 1e9, n + 1, nices)
        nices.add(nice)
    return out


def record_once(config: RigConfig, frames: list, seconds: float, path: Path) -> dict:
    """One recording with the live estimate; what the file holds and lost, the estimate's
    rate and skips, the threads' time by group."""
    rig = replay_rig(config, frames)
    calibration = calibration_from_rig(true_rig(config))
    settings = config.live
    estimator = FrameEstimator(
        untrained_model([32, 64, 256]),
        calibration,
        config.sgbm,
        scale=settings.scale,
        row_scale=settings.row_scale,
        depth_margin_mm=settings.depth_margin_mm,
    )
    recorder = session_recorder(config, path, rig, streams=(marks_stream(),))
    run = LiveRun(recorder, estimator, max_frame_age_s=settings.max_frame_age_s)
    writes = time_the_writes(recorder)
    snapshots: list[dict] = [thread_times()]

    def sample(status: object) -> None:
        snapshots.append({**snapshots[-1], **thread_times()})  # ended threads keep their last

    run.start()
    t0 = time.monotonic()
    status = run_headless(run, seconds, sample)
    wall = time.monotonic() - t0
    if run.error:
        raise SystemExit(f"live run failed: {run.error}")
    with SessionReader(path) as reader:
        t_host = reader.stream_times(CAMERA)[1][: reader.n_frames]
        seqs = reader.stream_times(CAMERA)[2][: reader.n_frames]
        attrs = dict(reader.attrs)
        gaps = [  # (seconds into the recording, frames lost)
            ((gap["t_host_ns"] - t_host[0]) / 1e9, gap["count"])
            for gap in reader.gaps()
            if gap["stream"] == CAMERA and len(t_host)
        ]
    return {
        "frames": len(seqs),
        "missing": int(seqs[-1] - seqs[0] + 1 - len(seqs)) if len(seqs) else 0,
        "gaps": gaps,
        "queue": int(attrs["camera_queue_dropped"]),
        "device": int(attrs["camera_device_dropped"]),
        "stored": int(attrs.get("camera_frames_stored", 0)),  # older sessions: none
        "mb": path.stat().st_size / 1e6,
        "rate": status.estimates / wall,
        "skipped": status.skipped / max(status.frames, 1),
        "wall": wall,
        "threads": time_by_group(snapshots[0], snapshots[-1]),
        "writes": [ns / 1e9 for ns in writes],
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--busy", type=int, default=1, help="busy processes beside the run")
    parser.add_argument("--size", default="640x360")
    args = smoke.parse(parser, argv, seconds=3.0, runs=1, size="320x180")
    width, height = (int(v) for v in args.size.split("x"))
    config = builtin_rig({"bench": {"width": width, "height": height, "fps": FPS}})
    use_threads(config.live)
    compression = config.record.compression
    frames = rendered_frames(config, REPLAY_FRAMES)
    print(
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; {width}x{height} "
        f"at {FPS:.0f} fps replayed through the OpenCV driver, {args.seconds:g} s per run, "
        f"{args.busy} busy process(es) beside it; recording compression {compression}, "
        f"PointNet 32-64-256 live"
    )
    print(
        f"{'run':>3} {'frames':>6} {'missing':>7} {'lost: queue':>11} {'device':>6} "
        f"{'stored raw':>10} {'MB':>6} {'est/s':>6} {'skipped':>7}"
    )
    with tempfile.TemporaryDirectory() as folder:
        for k in range(args.runs):
            busy = [subprocess.Popen(["yes"], stdout=subprocess.DEVNULL) for _ in range(args.busy)]
            try:
                r = record_once(config, frames, args.seconds, Path(folder) / f"run-{k}.h5")
            finally:
                for process in busy:
                    process.kill()
                    process.wait()
            print(
                f"{k + 1:>3} {r['frames']:>6} {r['missing']:>7} {r['queue']:>11} "
                f"{r['device']:>6} {r['stored']:>10} {r['mb']:6.0f} {r['rate']:6.1f} "
                f"{r['skipped']:7.0%}",
                flush=True,
            )
            for at_s, count in r["gaps"]:
                print(f"    {count} frames lost at {at_s:.1f} s")
            wall, cpu, wait = r["writes"]
            print(
                f"    writing the frames: {wall:5.1f} s = on CPU {cpu:5.1f} s + waiting for a CPU "
                f"{wait:5.1f} s + blocked (GIL, locks, I/O) {wall - cpu - wait:5.1f} s"
            )
            for group, (cpu, wait, n, nices) in sorted(r["threads"].items()):
                blocked = n * r["wall"] - cpu - wait
                print(
                    f"    {group:<30} {n:>2} threads, nice {sorted(nices)}: on CPU {cpu:5.1f} s, "
                    f"waiting for a CPU {wait:5.1f} s, blocked or idle {blocked:6.1f} s"
                )
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
