"""The console's UI event loop latency while it records 640x360 and estimates live.

A precise 10 ms Qt timer probes the window's event loop: its latency is how late each tick comes
(p50/p95, ms). The console (``vbfe console``'s window, the Live tab in view: images and traces each
redrawn every 100 ms, on alternate 50 ms ticks) records the bench at 640x360 30 fps with the live
estimate of the demo's PointNet (untrained weights: speed does not depend on them); the endoscope
replays frames the bench rendered beforehand (as benchmarks/bench_live.py: a real endoscope's frames
cost the host nothing to make). The reference is the same probe in the same process with the window
closed and nothing running. ``--background-load N`` adds N busy processes (the issue's target: p95
at most 50 ms with one). Also prints the estimate rate and latency and the recording's drops.
Run: ``python -m benchmarks.bench_console [--seconds 10] [--background-load 1]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from pyqtgraph.Qt import QtCore

sys.path[:0] = [str(Path(__file__).parent), str(Path(__file__).parent.parent)]  # bench_live, tests

from bench_live import busy_processes, rendered_frames, replay_rig, untrained_model  # noqa: E402

from benchmarks import smoke  # noqa: E402
from vbfe.console.station import SessionRequest, Station  # noqa: E402
from vbfe.console.window import ConsoleOptions, ConsoleWindow  # noqa: E402
from vbfe.drivers.qt_app import dispose_widget, qt_application  # noqa: E402
from vbfe.live.run import use_threads  # noqa: E402
from vbfe.rig_config import RigConfig, builtin_rig  # noqa: E402
from vbfe.truth import calibration_from_rig, true_rig  # noqa: E402

PROBE_MS = 10
FPS = 30.0


def probe_latency(seconds: float, until=None) -> np.ndarray:
    """Run the event loop for ``seconds`` (or until ``until()``), a ``PROBE_MS`` timer ticking;
    how late each tick came, in ms."""
    app = qt_application()
    ticks: list[float] = []
    timer = QtCore.QTimer()
    timer.setTimerType(QtCore.Qt.TimerType.PreciseTimer)
    timer.timeout.connect(lambda: ticks.append(time.monotonic()))
    timer.start(PROBE_MS)
    end = time.monotonic() + seconds
    while time.monotonic() < end and not (until and until()):
        app.processEvents(QtCore.QEventLoop.ProcessEventsFlag.AllEvents, 5)
        time.sleep(0.001)
    timer.stop()
    return np.maximum(np.diff(ticks) * 1e3 - PROBE_MS, 0.0)


def console_run(config: RigConfig, frames: list[np.ndarray], seconds: float, folder: Path) -> dict:
    """Record ``seconds`` with the live estimate in the console; the probe's latencies and
    what the recording and the estimate achieved."""
    from vbfe.live.estimator import FrameEstimator

    settings = config.live
    use_threads(settings)
    calibration = calibration_from_rig(true_rig(config))
    estimator = FrameEstimator(
        untrained_model([32, 64, 256]),
        calibration,
        config.sgbm,
        scale=settings.scale,
        row_scale=settings.row_scale,
        depth_margin_mm=settings.depth_margin_mm,
    )
    station = Station(
        config,
        calibration,
        estimator=estimator,
        rig_factory=lambda cfg, options: replay_rig(cfg, frames),
    )
    window = ConsoleWindow(station, ConsoleOptions(folder, live_when_idle=False))
    window.show()
    window.tabs.setCurrentWidget(window.live_tab)
    finished = []
    window.finished_hooks.append(finished.append)
    statuses = []

    def ended() -> bool:
        status = station.live_status()
        if status is not None:
            statuses.append(status)
        return bool(finished)

    window.confirm_close = False  # nobody to ask: the benchmark closes the window itself
    request = SessionRequest(folder / "console.h5", duration_s=seconds)
    window.rig_op(station.start_recording, request)
    probe_latency(30.0, until=lambda: station.recording is not None)
    probe_latency(1.0)  # warm-up: the estimator's first frames
    latency = probe_latency(seconds + 30.0, until=ended)
    window.close()
    dispose_widget(window)
    if window.errors or not finished:
        raise SystemExit(f"console run failed: {window.errors}")
    return {"latency": latency, "status": statuses[-1] if statuses else None, **vars(finished[0])}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--background-load", type=int, default=0, metavar="N")
    args = smoke.parse(parser, argv, seconds=1.0, background_load=0)
    config = builtin_rig({"bench": dict(width=640, height=360, fps=FPS)})
    frames = rendered_frames(config, 60)
    print(
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; console recording "
        f"640x360 at {FPS:.0f} fps (replayed bench frames) with the live estimate; probe "
        f"timer {PROBE_MS} ms"
    )
    print(f"{'run':>28} {'busy':>4} {'p50 ms':>7} {'p95 ms':>7} {'ratio p95':>9}  live / recorded")
    for load in sorted({0, args.background_load}):
        busy = busy_processes(load)
        try:
            reference = probe_latency(args.seconds)
            with tempfile.TemporaryDirectory() as folder:
                run = console_run(config, frames, args.seconds, Path(folder))
        finally:
            for process in busy:
                process.kill()
                process.wait()
        ref95 = float(np.percentile(reference, 95))
        print(
            f"{'reference (idle event loop)':>28} {load:>4} {np.percentile(reference, 50):7.2f} "
            f"{ref95:7.2f} {1.0:9.2f}"
        )
        lat = run["latency"]
        status = run["status"]
        live = (
            f"{status.rate_hz:.1f} est/s, latency p50 {status.latency_p50_ms:.0f} ms p95 "
            f"{status.latency_p95_ms:.0f} ms"
            if status is not None
            else "no estimate"
        )
        p95 = float(np.percentile(lat, 95))
        print(
            f"{'console record + estimate':>28} {load:>4} {np.percentile(lat, 50):7.2f} "
            f"{p95:7.2f} {p95 / max(ref95, 1e-3):9.2f}  {live}; {run['stats'].frames} frames "
            f"recorded, dropped {run['stats'].dropped}",
            flush=True,
        )
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
