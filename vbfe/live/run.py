"""A live run: a listener of the rig's acquisition hands the newest frame to the estimator and
the trocar's samples to a short history; the estimates come out with their latency and error.

With a session path the acquisition is a recorder (the rig is recorded as by ``vbfe record``)
and each estimate goes into the session's ``/estimate`` stream as it comes, flushed with the
frames (a recorder that dies keeps them up to its last flush); the run's counts are added
when it ends.
"""

from __future__ import annotations

import bisect
import collections
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from vbfe.acquire import Acquisition, Listener, Recorder, SessionReader
from vbfe.acquire.image_size import size_mismatch
from vbfe.acquire.recording.record import session_recorder
from vbfe.acquire.resample import resample_at
from vbfe.acquire.session.annotate import store_estimate_counts
from vbfe.acquire.session.estimates import GROUP as ESTIMATES
from vbfe.acquire.session.estimates import EstimateRecord, estimate_stream_spec
from vbfe.acquire.session.extra_streams import marks_stream
from vbfe.acquire.session.layout import CAMERA
from vbfe.calib import Calibration
from vbfe.common.errors import LiveError
from vbfe.common.signals import Terminated
from vbfe.drivers import ForceSample, StereoFrame
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.registry import open_rig
from vbfe.drivers.rig import RigOptions
from vbfe.estimate import ForceModel
from vbfe.estimate.preparation import force_target
from vbfe.live.estimator import STAGES, FrameEstimator, FrameWork, LiveEstimate
from vbfe.live.outputs import EstimateOutput
from vbfe.live.pipeline import Pipeline
from vbfe.live.settings import LiveConfig, LiveSettings

FORCE_HISTORY_S = 30.0


class LiveCurves(NamedTuple):
    """What the viewer draws: times in seconds before now, forces in newtons."""

    t_estimate_s: np.ndarray
    estimate_n: np.ndarray
    t_trocar_s: np.ndarray
    trocar_n: np.ndarray
    lo_n: np.ndarray  # the estimate's interval (NaN: none, or three axes)
    hi_n: np.ndarray
    ood: np.ndarray  # the estimate's frame is outside the training data


@dataclass
class LiveStatus:
    """What the status line and the viewer show."""

    wall_s: float
    frames: int  # frames the camera delivered
    estimates: int
    skipped: int  # frames replaced by a newer one before a stage took them, or come too late
    rate_hz: float  # estimates per second over the last few seconds
    latency_p50_ms: float
    latency_p95_ms: float
    mae_n: float  # running MAE against the trocar (raw host times), NaN without trocar data
    mae_count: int
    last_estimate_n: float
    last_trocar_n: float

    def line(self) -> str:
        """One status line for headless runs."""
        mae = (
            f"MAE vs trocar {self.mae_n:.3f} N (n={self.mae_count})"
            if self.mae_count
            else "MAE vs trocar -"
        )
        return (
            f"live {self.wall_s:6.1f} s | {self.rate_hz:5.1f} est/s | latency p50 "
            f"{self.latency_p50_ms:5.1f} ms p95 {self.latency_p95_ms:5.1f} ms | skipped "
            f"{self.skipped} of {self.frames} frames | {mae} | estimate "
            f"{self.last_estimate_n:+.2f} N trocar {self.last_trocar_n:+.2f} N"
        )


def use_threads(settings: LiveSettings) -> None:
    """Size torch's and OpenCV's thread pools as ``[live]`` says (OpenCV's 0: one per core)."""
    import cv2
    import torch

    torch.set_num_threads(settings.torch_threads)
    cv2.setNumThreads(settings.opencv_threads or os.cpu_count() or 1)


def live_estimator(
    config: LiveConfig,
    model: ForceModel,
    calibration: Calibration,
    scale: float | None = None,
    verify: bool = True,
    device: str | None = None,
    row_scale: float | None = None,
) -> FrameEstimator:
    """The estimator of a live run: ``[sgbm]``, the ``[live]`` defaults where ``scale``,
    ``row_scale`` and ``device`` are not given (``auto``: CUDA when torch sees it), torch's
    and OpenCV's thread counts."""
    import torch

    settings = config.live
    device = device or settings.device
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    elif device == "cuda" and not torch.cuda.is_available():
        raise LiveError("--device cuda: torch sees no CUDA device; use --device cpu")
    use_threads(settings)
    return FrameEstimator(
        model,
        calibration,
        config.sgbm,
        verify=verify and settings.verify,
        scale=scale or settings.scale,
        device=device,
        row_scale=row_scale or settings.row_scale,
        depth_margin_mm=settings.depth_margin_mm,
        protocol=settings.protocol or None,
    )


def live_run(
    config: LiveConfig,
    estimator: FrameEstimator,
    calibration: Calibration,
    calibration_name: str,
    record: str | Path | None = None,
    model_name: str = "",
    outputs: Sequence[EstimateOutput] = (),
) -> LiveRun:
    """The live run over the config's rig, run at the camera's own pace (a simulated one in
    real time too), recording into ``record`` when given, handing every estimate to
    ``outputs``; not started yet. The calibration must be of the camera's mode."""
    rig = open_rig(config, RigOptions(realtime=True))
    mismatch = size_mismatch(
        "the camera delivers",
        (rig.camera.width, rig.camera.height),
        calibration_name,
        calibration.image_size,
    )
    if mismatch:
        raise LiveError(mismatch)
    acquisition = (
        session_recorder(
            config,
            record,
            rig,
            calibration_yaml=calibration.to_yaml_text(),
            streams=(marks_stream(),),
        )
        if record
        else Acquisition(rig, pattern=make_pattern)
    )
    return LiveRun(
        acquisition,
        estimator,
        model_name,
        outputs,
        config.live.max_frame_age_s,
    )


class LiveRun(Listener):
    """Run the estimator on the newest frames of an acquisition until :meth:`stop` (it adds
    itself as a listener, and ``outputs`` after it; with a :class:`Recorder` the run is
    recorded, each estimate into its ``/estimate`` stream as it comes). The estimator's stages
    run as a :class:`Pipeline`, each on its own thread (beside a recording at a lower priority).

    The recording comes first: the run is a lossy listener (it takes the newest frame on the
    acquisition's live thread, never the writer's), and a frame that reaches it more than
    ``max_frame_age_s`` after its capture (0: no limit) is skipped, the machine being behind.
    Every frame the estimate did not use is counted in the status's ``skipped``; the first
    frame never is (the acquisition and the pipeline pin it): it is the estimator's rest
    reference, as the first frame of the recording is offline.
    """

    lossy = True

    def __init__(
        self,
        acquisition: Acquisition,
        estimator: FrameEstimator,
        model_name: str = "",
        outputs: Sequence[EstimateOutput] = (),
        max_frame_age_s: float = 0.25,
    ) -> None:
        acquisition.add(self)
        for output in outputs:
            acquisition.add(output)
        self.outputs = tuple(outputs)
        self.acquisition = acquisition
        if isinstance(acquisition, Recorder):
            settings = {
                "target": estimator.model.config.target,
                "outputs": estimator.model.config.n_outputs,
                "scale": estimator.scale,
                "row_scale": estimator.row_scale,
                "model": model_name,
                "method": estimator.model.selected,  # the model's method for this protocol
            }
            outputs_n = estimator.model.config.n_outputs
            acquisition.sink.add_stream(estimate_stream_spec(outputs_n, STAGES, settings))
        self.estimator, self.model_name = estimator, model_name
        self.target = estimator.model.config.target
        self._pipeline = Pipeline(
            self._stages(), self._record, yield_to_recording=isinstance(acquisition, Recorder)
        )
        self._frames_seen = self._frames_late = 0
        self._max_age_ns = max_frame_age_s * 1e9 or float("inf")
        rate = float(acquisition.rig.trocar.rate_hz or 1000.0)
        self._forces: collections.deque = collections.deque(maxlen=int(rate * FORCE_HISTORY_S))
        self.estimates: list[LiveEstimate] = []
        self._trocar_at_estimates: list[float] = []
        self._abs_error_sum, self._abs_error_count = 0.0, 0
        self._lock = threading.Lock()
        self.error: str | None = None
        self._t0 = 0.0

    def _stages(self) -> list[tuple[str, Callable[[Any], Any]]]:
        """The estimator's stages, its reconstruction handing each cloud to the outputs."""
        (name, reconstruct), *rest = self.estimator.stages()

        def reconstruct_and_hand_on(work: FrameWork) -> FrameWork | LiveEstimate:
            done = reconstruct(work)  # an estimate already when the frame is refused
            if isinstance(done, FrameWork) and done.points is not None and done.colors is not None:
                for output in self.outputs:
                    output.on_cloud(done.frame.t_host_ns, done.points, done.colors)
            return done

        return [(name, reconstruct_and_hand_on), *rest]

    # -- lifecycle --------------------------------------------------------------------------
    def start(self, duration_s: float | None = None) -> None:
        """Start the acquisition (keeping ``duration_s`` of frames when given) and estimating."""
        self._t0 = time.monotonic()
        self.acquisition.start(duration_s)

    def running(self) -> bool:
        """False once the acquisition ended (duration, device gone) or estimation failed."""
        return self.acquisition.running() and self._pipeline.error is None

    def stop(self, reason: str = "stopped by operator") -> LiveStatus:
        """Stop the acquisition and the estimator; when recording, store the estimate stream
        in the finalized session. A failure, or a device lost without a recording, is kept in
        ``error``."""
        lost = self.acquisition.lost()
        try:
            self.acquisition.stop(reason)
        except Exception as exc:  # noqa: BLE001 - reported by the command
            self.error = str(exc)
        recorder = self.acquisition if isinstance(self.acquisition, Recorder) else None
        if lost and recorder is None and self.error is None:
            self.error = lost
        if self._pipeline.error is not None and self.error is None:
            self.error = self._pipeline.error
        status = self.status()
        if recorder is not None and self.error is None:
            with SessionReader(recorder.path) as reader:
                recorded = reader.stream_times(CAMERA)[2][: reader.n_frames]
            store_estimate_counts(recorder.path, self.counts(status, recorded))
        return status

    def mark(self, text: str) -> bool:
        """Put an event mark at the host's now into the recording; False when not recording."""
        if not isinstance(self.acquisition, Recorder):
            return False
        self.acquisition.sink.mark(text, time.monotonic_ns())
        return True

    # -- listener hooks ---------------------------------------------------------------------
    def on_start(self, acquisition: Acquisition) -> None:
        self._pipeline.start()

    def on_frames(self, frames: Sequence[StereoFrame]) -> None:
        for frame in frames:
            self._frames_seen += 1
            if self._frames_seen == 1:  # the rest reference: never skipped, however late
                self._pipeline.put(FrameWork(frame), pinned=True)
            elif time.monotonic_ns() - frame.t_host_ns > self._max_age_ns:
                self._frames_late += 1
            else:
                self._pipeline.put(FrameWork(frame))

    def on_samples(self, samples: Sequence[ForceSample]) -> None:
        self._forces.extend(samples)

    def on_stop(self, acquisition: Acquisition) -> None:
        self._pipeline.stop()

    def _record(self, estimate: LiveEstimate) -> None:
        """Keep an estimate (with the trocar's force at its frame) and hand it to the outputs
        (on the pipeline's last thread)."""
        trocar = self._trocar_at(estimate.t_frame_host_ns)
        value = self._scalars(estimate.force_n[None])[0]
        with self._lock:
            self.estimates.append(estimate)
            count = len(self.estimates)
            self._trocar_at_estimates.append(trocar)
            if np.isfinite(value) and np.isfinite(trocar):
                self._abs_error_sum += abs(value - trocar)
                self._abs_error_count += 1
        if isinstance(self.acquisition, Recorder):
            self.acquisition.sink.post(ESTIMATES, [EstimateRecord(estimate, count - 1)])
        for output in self.outputs:
            output.on_estimate(estimate)

    # -- what is seen (cheap: the viewer and the status poll it while the pipeline runs) ----
    def _scalars(self, forces: np.ndarray) -> np.ndarray:
        """Forces (n × outputs) as one number each: the value, or the norm of x, y, z."""
        return forces[:, 0] if forces.shape[1] == 1 else np.linalg.norm(forces, axis=1)

    def _forces_since(self, t_host_ns: float) -> list[ForceSample]:
        """The trocar samples from ``t_host_ns`` on, and the one before (host time order)."""
        samples: list[ForceSample] = list(self._forces)
        start = bisect.bisect_left(samples, t_host_ns, key=lambda s: s.t_host_ns)
        return samples[max(0, start - 1) :]

    def _trocar_at(self, t_host_ns: int) -> float:
        """The trocar's force (in the model's target, as one number) at a host time."""
        samples = self._forces_since(t_host_ns)[:3]
        if len(samples) < 2:
            return float("nan")
        force = resample_at(
            np.array([t_host_ns]),
            np.array([s.t_host_ns for s in samples]),
            np.array([s.force_n for s in samples]),
        )
        return float(self._scalars(force_target(force, self.target))[0])

    def status(self) -> LiveStatus:
        """Counts, rate, latency and running error so far."""
        now_ns = time.monotonic_ns()
        with self._lock:
            last = self.estimates[-300:]
            count, trocar = len(self.estimates), self._trocar_at_estimates[-1:]
            mae_sum, mae_count = self._abs_error_sum, self._abs_error_count
        wall = time.monotonic() - self._t0
        latency = np.array([e.latency_s for e in last]) * 1e3
        recent = sum(e.t_ready_host_ns >= now_ns - 3e9 for e in last)
        window = min(3.0, wall)
        unseen = self.acquisition.live_skipped  # replaced before the run took them
        return LiveStatus(
            wall_s=wall,
            frames=self._frames_seen + unseen,
            estimates=count,
            skipped=self._pipeline.skipped + self._frames_late + unseen,
            rate_hz=recent / window if window > 0 else 0.0,
            latency_p50_ms=float(np.percentile(latency, 50)) if len(latency) else float("nan"),
            latency_p95_ms=float(np.percentile(latency, 95)) if len(latency) else float("nan"),
            mae_n=mae_sum / mae_count if mae_count else float("nan"),
            mae_count=mae_count,
            last_estimate_n=(
                float(self._scalars(last[-1].force_n[None])[0]) if last else float("nan")
            ),
            last_trocar_n=trocar[0] if trocar else float("nan"),
        )

    def curves(self, window_s: float, max_points: int = 2000) -> LiveCurves:
        """Estimate (with its interval and flag) and trocar, the model target as one number,
        against host time in seconds over the last ``window_s``; each curve thinned to at
        most ``max_points`` points."""
        now = time.monotonic_ns()
        since = now - window_s * 1e9
        with self._lock:
            start = bisect.bisect_left(self.estimates, since, key=lambda e: e.t_frame_host_ns)
            estimates = self.estimates[start:]
        estimates = estimates[:: len(estimates) // max_points + 1]
        samples = self._forces_since(since)
        samples = samples[:: len(samples) // max_points + 1]
        t_est = np.array([e.t_frame_host_ns for e in estimates], np.float64)

        def scalars(key: str) -> np.ndarray:
            values = [getattr(e, key) for e in estimates]
            if not estimates:
                return np.zeros(0)
            return self._scalars(np.array(values, np.float64).reshape(len(estimates), -1))

        one = self.estimator.model.config.n_outputs == 1  # three axes: no band of |F|
        t_trc = np.array([s.t_host_ns for s in samples], np.float64)
        trc = (
            self._scalars(force_target(np.array([s.force_n for s in samples]), self.target))
            if samples
            else np.zeros(0)
        )
        return LiveCurves(
            (t_est - now) / 1e9,
            scalars("force_n"),
            (t_trc - now) / 1e9,
            trc,
            scalars("lo_n") if one else np.full(len(t_est), np.nan),
            scalars("hi_n") if one else np.full(len(t_est), np.nan),
            np.array([e.ood for e in estimates], bool),
        )

    def counts(self, status: LiveStatus, recorded_seqs: np.ndarray) -> dict[str, Any]:
        """What the run's ``/estimate`` stream adds at the end: frames seen, estimated and
        skipped, the estimates of frames the recording does not hold (past its end, or lost
        by the recorder: not read back), the running error."""
        with self._lock:
            seqs = [e.frame_seq for e in self.estimates]
        return {
            "frames_seen": status.frames,
            "estimated": status.estimates,
            "of_unrecorded_frames": int((~np.isin(seqs, recorded_seqs)).sum()),
            "skipped_frames": status.skipped,
            "running_mae_n": status.mae_n,
        }


def run_headless(
    run: LiveRun,
    duration_s: float | None,
    on_status: Callable[[LiveStatus], None],
    interval_s: float = 1.0,
) -> LiveStatus:
    """Wait until ``duration_s`` (wall clock), the end of the recording, Ctrl-C or SIGTERM
    (the run's normal ends: the session is finished), reporting the status every
    ``interval_s``; then stop the run."""
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
    except Terminated:
        reason = "stopped by SIGTERM"
    except KeyboardInterrupt:
        reason = "stopped by operator"
    return run.stop(reason)
