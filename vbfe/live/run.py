"""A live run: devices (recorded or not) feed the newest frame to the estimator, the trocar's
samples to a short history, and the estimates come out with their latency and error.

With a session path, the rig is recorded as by ``vbfe record`` (the devices are tapped, not
taken over) and the estimate stream is stored in the session when the run ends.
"""

from __future__ import annotations

import collections
import contextlib
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from vbfe.acquire import EstimateStream, SessionReader, store_estimates
from vbfe.acquire.recording.recorder import Recorder
from vbfe.drivers.errors import DeviceError
from vbfe.drivers.registry import Devices
from vbfe.drivers.samples import ForceSample, StereoFrame
from vbfe.estimate.preparation import force_target
from vbfe.live.estimator import STAGES, FrameEstimator, LiveEstimate
from vbfe.live.mailbox import Mailbox
from vbfe.recon import make_pattern

_READ_TIMEOUT_S = 0.2
FORCE_HISTORY_S = 30.0


class _Tap:
    """A device proxy that hands every item it reads to ``on_item``; all else is the device's."""

    def __init__(self, device: Any, on_item: Callable[[Any], None]) -> None:
        self._device, self._on_item = device, on_item

    def read(self, timeout_s: float = 1.0) -> Any:
        item = self._device.read(timeout_s)
        if item is not None:
            self._on_item(item)
        return item

    def __getattr__(self, name: str) -> Any:
        return getattr(self._device, name)


@dataclass
class LiveStatus:
    """What the status line and the viewer show."""

    wall_s: float
    frames: int  # frames the camera delivered
    estimates: int
    skipped: int  # frames replaced by a newer one before the estimator took them
    rate_hz: float  # estimates per second over the last few seconds
    latency_p50_ms: float
    latency_p95_ms: float
    mae_n: float  # running MAE against the trocar (raw host times), NaN without trocar data
    mae_count: int
    last_estimate_n: float
    last_trocar_n: float

    def line(self) -> str:
        """One status line for headless runs."""
        mae = (f"MAE vs trocar {self.mae_n:.3f} N (n={self.mae_count})" if self.mae_count
               else "MAE vs trocar -")
        return (f"live {self.wall_s:6.1f} s | {self.rate_hz:5.1f} est/s | latency p50 "
                f"{self.latency_p50_ms:5.1f} ms p95 {self.latency_p95_ms:5.1f} ms | skipped "
                f"{self.skipped} of {self.frames} frames | {mae} | estimate "
                f"{self.last_estimate_n:+.2f} N trocar {self.last_trocar_n:+.2f} N")


class LiveRun:
    """Run the estimator on a rig's newest frames until :meth:`stop`.

    A recorder given to :meth:`start` must be built over ``self.devices`` (the tapped
    devices); it then owns them, else this run opens them and shows the pattern itself.
    """

    def __init__(self, devices: Devices, estimator: FrameEstimator, model_name: str = "") -> None:
        self.estimator, self.model_name = estimator, model_name
        self.target = estimator.model.config.target
        self._frames: Mailbox[StereoFrame] = Mailbox()
        rate = float(getattr(devices.trocar, "rate_hz", 1000.0) or 1000.0)
        self._forces: collections.deque = collections.deque(maxlen=int(rate * FORCE_HISTORY_S))
        self.devices = Devices(camera=_Tap(devices.camera, self._frames.put),
                               trocar=_Tap(devices.trocar, self._forces.append),
                               projector=devices.projector, bench=devices.bench)
        self.estimates: list[LiveEstimate] = []
        self._trocar_at_estimates: list[float] = []
        self._lock = threading.Lock()
        self._halt = threading.Event()
        self._threads: list[threading.Thread] = []
        self._recorder: Recorder | None = None
        self._recorder_done = threading.Event()
        self.error: str | None = None
        self._t0 = 0.0

    # -- lifecycle --------------------------------------------------------------------------
    def start(self, recorder: Recorder | None = None, duration_s: float | None = None) -> None:
        """Start reading (through ``recorder`` when given) and estimating."""
        self._t0 = time.monotonic()
        self._recorder = recorder
        if recorder is not None:
            recorder.start()
            self._spawn(self._record, recorder, duration_s)
        else:
            self._open_devices()
            self._spawn(self._pump, self.devices.camera)
            self._spawn(self._pump, self.devices.trocar)
        self._spawn(self._estimate_loop)

    def running(self) -> bool:
        """False once the recording ended (duration, device gone) or a pump failed."""
        return not (self._halt.is_set() or self._recorder_done.is_set())

    def stop(self, reason: str = "stopped by operator") -> LiveStatus:
        """Stop reading and estimating; with a recorder, finalize the session and store the
        estimate stream in it."""
        if self._recorder is not None:
            if not self._recorder_done.is_set():
                self._recorder.request_stop(reason)
            self._recorder_done.wait()
        self._halt.set()
        for thread in self._threads:
            thread.join()
        if self._recorder is None:
            for device in (self.devices.camera, self.devices.trocar, self.devices.projector):
                with contextlib.suppress(DeviceError):
                    device.close()
        status = self.status()
        if self._recorder is not None and self.error is None:
            with SessionReader(self._recorder.path) as reader:
                recorded = reader.stream_times("camera")[2][:reader.n_frames]
            store_estimates(self._recorder.path, self.stream(status, recorded))
        return status

    # -- threads ------------------------------------------------------------------------------
    def _spawn(self, target: Callable[..., None], *args: Any) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True,
                                  name=f"vbfe-live-{target.__name__.strip('_')}")
        self._threads.append(thread)
        thread.start()

    def _open_devices(self) -> None:
        opened = []
        try:
            for device in (self.devices.camera, self.devices.trocar, self.devices.projector):
                device.open()
                opened.append(device)
        except DeviceError:
            for device in opened:
                device.close()
            raise
        projector = self.devices.projector
        projector.show(make_pattern(projector.width, projector.height), "debruijn-hsv")

    def _record(self, recorder: Recorder, duration_s: float | None) -> None:
        try:
            recorder.run(duration_s)
        except Exception as exc:  # noqa: BLE001 - reported by the command after stop()
            self.error = str(exc)
        finally:
            self._recorder_done.set()

    def _pump(self, device: Any) -> None:
        while not self._halt.is_set():
            try:
                device.read(_READ_TIMEOUT_S)
            except DeviceError as exc:
                self.error = str(exc)
                self._halt.set()

    def _estimate_loop(self) -> None:
        while not self._halt.is_set():
            frame = self._frames.take(_READ_TIMEOUT_S)
            if frame is None:
                continue
            estimate = self.estimator.estimate(frame)
            trocar = self._trocar_at(estimate.t_frame_host_ns)
            with self._lock:
                self.estimates.append(estimate)
                self._trocar_at_estimates.append(trocar)

    # -- what is seen ---------------------------------------------------------------------------
    def _scalar(self, force: np.ndarray) -> float:
        return float(force[0]) if len(force) == 1 else float(np.linalg.norm(force))

    def _trocar_at(self, t_host_ns: int) -> float:
        """The trocar's force (in the model's target, as one number) at a host time."""
        samples: list[ForceSample] = list(self._forces)
        if len(samples) < 2 or not samples[0].t_host_ns <= t_host_ns <= samples[-1].t_host_ns:
            return float("nan")
        t = np.array([s.t_host_ns for s in samples], np.float64)
        forces = np.array([s.force_n for s in samples], np.float64)
        force = np.array([np.interp(t_host_ns, t, forces[:, k]) for k in range(3)])
        return self._scalar(force_target(force[None], self.target)[0])

    def status(self) -> LiveStatus:
        """Counts, rate, latency and running error so far."""
        with self._lock:
            estimates = list(self.estimates)
            trocar = np.array(self._trocar_at_estimates, np.float64)
        wall = time.monotonic() - self._t0
        latency = np.array([e.latency_s for e in estimates[-300:]]) * 1e3
        recent = [e for e in estimates if e.t_ready_host_ns >= time.monotonic_ns() - 3e9]
        window = min(3.0, wall)
        values = np.array([self._scalar(e.force_n) for e in estimates], np.float64)
        ok = np.isfinite(values) & np.isfinite(trocar)
        return LiveStatus(
            wall_s=wall, frames=self._frames.put_count, estimates=len(estimates),
            skipped=self._frames.skipped, rate_hz=len(recent) / window if window > 0 else 0.0,
            latency_p50_ms=float(np.percentile(latency, 50)) if len(latency) else float("nan"),
            latency_p95_ms=float(np.percentile(latency, 95)) if len(latency) else float("nan"),
            mae_n=float(np.mean(np.abs(values[ok] - trocar[ok]))) if ok.any() else float("nan"),
            mae_count=int(ok.sum()),
            last_estimate_n=float(values[-1]) if len(values) else float("nan"),
            last_trocar_n=float(trocar[-1]) if len(trocar) else float("nan"))

    def curves(self, window_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Estimate and trocar (model target as one number) against host time in seconds,
        over the last ``window_s``: ``(t_est, est, t_trocar, trocar)``."""
        with self._lock:
            estimates = list(self.estimates)
        samples = list(self._forces)
        now = time.monotonic_ns()
        est = [(e.t_frame_host_ns, self._scalar(e.force_n)) for e in estimates
               if e.t_frame_host_ns >= now - window_s * 1e9]
        trc = samples[-int(len(samples) * min(1.0, window_s / FORCE_HISTORY_S)):]
        t_trc = np.array([s.t_host_ns for s in trc], np.float64)
        f_trc = (np.array([self._scalar(v) for v in force_target(
            np.array([s.force_n for s in trc]), self.target)]) if trc else np.zeros(0))
        t_est = np.array([t for t, _ in est], np.float64)
        return ((t_est - now) / 1e9, np.array([v for _, v in est]), (t_trc - now) / 1e9, f_trc)

    def stream(self, status: LiveStatus, recorded_seqs: np.ndarray) -> EstimateStream:
        """The estimates of the recorded frames as the session's ``/estimate`` stream (a
        frame past the recording's end, or lost by the recorder, keeps no estimate)."""
        with self._lock:
            kept = np.isin([e.frame_seq for e in self.estimates], recorded_seqs)
            estimates = [e for e, k in zip(self.estimates, kept) if k]
        outputs = self.estimator.model.config.n_outputs
        return EstimateStream(
            force_n=np.array([e.force_n for e in estimates], np.float64).reshape(-1, outputs),
            frame_seq=np.array([e.frame_seq for e in estimates], np.int64),
            t_frame_host_ns=np.array([e.t_frame_host_ns for e in estimates], np.int64),
            t_ready_host_ns=np.array([e.t_ready_host_ns for e in estimates], np.int64),
            stage_s=np.array([e.stage_s for e in estimates], np.float64).reshape(-1, len(STAGES)),
            stages=list(STAGES),
            attrs={"target": self.target, "outputs": outputs, "frames_seen": status.frames,
                   "estimated": status.estimates, "of_unrecorded_frames": int((~kept).sum()),
                   "skipped_frames": status.skipped, "scale": self.estimator.scale,
                   "running_mae_n": status.mae_n, "model": self.model_name})


def run_headless(run: LiveRun, duration_s: float | None, on_status: Callable[[LiveStatus], None],
                 interval_s: float = 1.0) -> LiveStatus:
    """Wait until ``duration_s`` (wall clock), the end of the recording, or Ctrl-C, reporting
    the status every ``interval_s``; then stop the run."""
    reason = "duration reached"
    try:
        next_report = time.monotonic() + interval_s
        while run.running():
            if duration_s is not None and run.status().wall_s >= duration_s:
                break
            time.sleep(0.05)
            if time.monotonic() >= next_report:
                on_status(run.status())
                next_report += interval_s
    except KeyboardInterrupt:
        reason = "stopped by operator"
    return run.stop(reason)
