"""The console's model (no Qt): the rig, the one acquisition running on it (a live view, a
recording or a sync protocol session, each the library's own object) and what the operator
asks of them.

Everything that opens, starts or stops the rig runs on one worker thread, in order
(:meth:`Station.submit` returns a future); the acquisition runs in a thread of its own. The view
only polls: :attr:`Station.latest` (newest frame, streams), :meth:`Station.stats`,
:meth:`Station.ended`.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vbfe.acquire import Acquisition, AcquisitionStats, Recorder
from vbfe.acquire.recording.latest import Latest
from vbfe.acquire.recording.record import (
    check_camera_size,
    session_recorder,
    store_frame_correction,
)
from vbfe.acquire.recording.sync_session import SyncProtocol
from vbfe.acquire.session.estimates import GROUP as ESTIMATE
from vbfe.acquire.session.extra_streams import MARKS, marks_stream
from vbfe.acquire.session.layout import CAMERA, FORCE, PROJECTOR
from vbfe.calib import Calibration, load_calibration
from vbfe.calib.commands import board_scene
from vbfe.common.errors import DeviceError, SessionError
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.registry import check_open, configured_devices, open_rig
from vbfe.drivers.rig import Rig, RigOptions
from vbfe.rig_config import RigConfig

if TYPE_CHECKING:  # the live estimate (torch) is imported only when a model is loaded
    from vbfe.live.estimator import FrameEstimator
    from vbfe.live.run import LiveRun, LiveStatus


@dataclass(frozen=True)
class SessionRequest:
    """A recording the operator asks for: the new file and what is stored with it."""

    path: Path
    operator: str = ""
    notes: str = ""
    conditions: dict[str, Any] = field(default_factory=dict)
    duration_s: float | None = None
    participant: str = ""
    task: str = ""


@dataclass(frozen=True)
class PlannedStream:
    """A stream a recording started now holds: its session name and where it comes from."""

    name: str
    source: str


def _camera_mode(tables: dict[str, dict[str, Any]]) -> str:
    """The camera's mode as the rig configuration sets it (the bench's for a simulated one)."""
    table = tables["bench"] if tables["camera"].get("backend") == "sim" else tables["camera"]
    if "width" not in table:
        return "the camera's default mode"
    fps = f" at {float(table['fps']):g} fps" if "fps" in table else ""
    return f"{table['width']}x{table['height']} per eye{fps}"


@dataclass(frozen=True)
class Finished:
    """A recording that ended: its file, the acquisition's final statistics, marks put in."""

    path: Path
    stats: AcquisitionStats
    marks: int

    def line(self) -> str:
        """One-line summary, as ``vbfe record`` prints it."""
        s = self.stats
        return (
            f"{self.path}: {s.frames} frames, {s.samples} force samples, {s.elapsed_s:.2f} s, "
            f"{self.marks} marks, dropped {sum(s.dropped.values())}; {s.end_reason}"
        )


class Station:
    """The rig of ``config`` and its one acquisition at a time.

    :param config: the rig configuration (:func:`vbfe.rig_config.load_rig`); ``[record]``
        settings apply to recordings as in ``vbfe record``, and every session stores which
        rig file it came from. What the operator changes replaces it (:meth:`reconfigure`).
    :param calibration: stored with every recording, and checked against the camera's mode.
    :param estimator: with one, every live view and recording runs the live estimate too.
    :param model_name: how the estimate stream names the model.
    :param rig_factory: builds the rig of a config for each acquisition (default
        :func:`~vbfe.drivers.registry.open_rig`; a benchmark may put its own devices in).
    """

    def __init__(
        self,
        config: RigConfig,
        calibration: Calibration | None = None,
        calibration_name: str = "the calibration",
        estimator: FrameEstimator | None = None,
        model_name: str = "",
        rig_factory: Callable[[RigConfig, RigOptions], Rig] = open_rig,
    ) -> None:
        self.config = config
        self._rig_factory = rig_factory
        self.calibration, self.calibration_name = calibration, calibration_name
        self.estimator, self.model_name = estimator, model_name
        self.latest = Latest()
        self.rig: Rig | None = None
        self.acquisition: Acquisition | None = None
        self.live: LiveRun | None = None
        self.recording: Path | None = None  # the session being recorded
        self.protocol: SyncProtocol | None = None  # the sync protocol being recorded
        self.last_session: Path | None = None
        self.device_errors: dict[str, str | None] = {}  # of the last failed start
        self.marks = 0
        self.pattern_on = False  # the live view shows the structured-light pattern
        self.board_scene = False  # the simulated bench shows the calibration board
        self.estimate_on = True  # the operator may switch the live estimate off
        self.model_path: Path | None = None
        self.finished: queue.SimpleQueue[Finished] = queue.SimpleQueue()  # for the view
        self._runner: threading.Thread | None = None
        self._run_error: BaseException | None = None
        self._ops = ThreadPoolExecutor(1, thread_name_prefix="vbfe-console-rig")

    def reconfigure(self, changes: dict[str, dict[str, Any]], where: str = "this window") -> None:
        """Use the configuration with ``changes`` (table -> key -> value) from the next
        acquisition on; checked first (a bad value: ConfigError naming the key, nothing
        changed)."""
        self.config = self.config.updated(changes, where)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        """Run ``fn(*args)`` on the rig's worker thread, after what was submitted before."""
        return self._ops.submit(fn, *args)

    # -- what the view polls ------------------------------------------------------------------
    def ended(self) -> bool:
        """Whether the running acquisition ended on its own (duration, device gone, disk full):
        :meth:`settle` finishes it."""
        return self._runner is not None and not self._runner.is_alive()

    def stats(self) -> AcquisitionStats | None:
        """The running acquisition's statistics (updated by its thread), if one runs."""
        acquisition = self.acquisition
        return None if acquisition is None else acquisition.stats

    def planned_streams(self) -> list[PlannedStream]:
        """What a recording started now holds, from the rig configuration: the camera's
        frames, the trocar's force, the projector's commands, each ``[streams]`` entry, the
        operator's markers and, with a model loaded and on, the live estimate."""
        what = {
            "camera": (CAMERA, f"stereo frames, {_camera_mode(self.config.tables)}"),
            "trocar": (FORCE, "force samples of the trocar"),
            "projector": (PROJECTOR, "pattern and flash commands to the projector"),
        }
        out = []
        for device in configured_devices(self.config):
            name, source = what.get(device.name, (device.name, f"LSL stream {device.settings}"))
            out.append(PlannedStream(name, f"{source} ({device.backend})"))
        out.append(PlannedStream(MARKS, "operator markers: the Marker button or the M key"))
        if self.estimator is not None and self.estimate_on:
            out.append(PlannedStream(ESTIMATE, f"live force estimate of {self.model_name}"))
        return out

    def live_status(self) -> LiveStatus | None:
        """The live estimate's status, when a model runs."""
        live = self.live
        return None if live is None else live.status()

    # -- worker-thread operations (call through submit) ----------------------------------------
    def go_live(self, pattern: bool = True, board: bool = False) -> None:
        """Show the rig live, nothing recorded: the structured-light pattern on, or (``pattern``
        false) the projector left dark, as calibration views need the board in room light;
        ``board``: the simulated bench shows the ``[calib]`` board (a real rig is as it is).
        A recording started meanwhile (remote control) is left alone."""
        if self.recording is not None:
            return
        self._end_current("live view restarted")
        config = board_scene(self.config) if board else self.config
        rig = self._open_rig(self._options(), config)
        if self.calibration is not None and self.estimator is not None and self.estimate_on:
            check_camera_size(rig, self.calibration.image_size, self.calibration_name)
        self._begin(Acquisition(rig, pattern=make_pattern if pattern else None))
        self.pattern_on = pattern

    def start_recording(self, request: SessionRequest) -> Path:
        """Record ``request.path`` (a new file; the event marks stream included) until
        :meth:`stop_recording` or its duration; the live view stops for it."""
        if self.recording is not None:
            raise SessionError(f"already recording {self.recording}; stop it first")
        rig = self._open_rig(self._options())
        if self.calibration is not None:
            check_camera_size(rig, self.calibration.image_size, self.calibration_name)
        recorder = session_recorder(
            self.config,
            request.path,
            rig,
            request.operator,
            request.notes,
            request.conditions,
            calibration_yaml=(
                self.calibration.to_yaml_text() if self.calibration is not None else None
            ),
            streams=(marks_stream(),),
            participant=request.participant,
            task=request.task,
        )
        self._end_current("recording starts")
        self._begin(recorder, request.duration_s)
        self.recording, self.marks = recorder.path, 0
        return recorder.path

    def start_sync_protocol(self, protocol: SyncProtocol, path: Path) -> Path:
        """Record a sync protocol session into ``path`` (its flashes and the simulated
        operator's taps as ``vbfe record --protocol sync``); it ends at its duration."""
        if self.recording is not None:
            raise SessionError(f"already recording {self.recording}; stop it first")
        rig = self._open_rig(protocol.rig_options())
        recorder = session_recorder(
            self.config, path, rig, notes="sync protocol session", listeners=(protocol,)
        )
        recorder.metadata["protocol"] = protocol.describe()
        self._end_current("sync protocol starts")
        self._begin(recorder, protocol.duration_s, estimate=False)
        self.recording, self.protocol, self.marks = recorder.path, protocol, 0
        return recorder.path

    def stop_recording(self, reason: str = "stopped by operator") -> Finished:
        """Stop the recording, finalize the session (with the ``[record]`` frame-time
        correction, as ``vbfe record``); the rig is left closed (:meth:`go_live` reopens).
        The summary is also put in :attr:`finished` for the view, whoever stopped it."""
        path = self.recording
        if path is None:
            raise SessionError("nothing is being recorded")
        try:
            stats = self._end_current(reason)
        finally:
            self.recording, self.protocol = None, None
        store_frame_correction(self.config, path)
        self.last_session = path
        finished = Finished(path, stats, self.marks)
        self.finished.put(finished)
        return finished

    def settle(self) -> Finished | str | None:
        """Finish an acquisition that ended on its own: a recording's summary, or why the
        live view ended; ``None`` when none has ended (the view polls :meth:`ended` from its
        own thread and may have seen a stop or restart half done: checked again here, after
        every operation submitted before)."""
        if not self.ended():
            return None
        if self.recording is not None:
            return self.stop_recording()
        acquisition = self.acquisition
        self._end_current("ended")
        return acquisition.stats.end_reason if acquisition is not None else ""

    def shutdown(self) -> Finished | None:
        """Finalize a running recording, close the rig, stop the worker (the window closes)."""

        def end() -> Finished | None:
            finished = self.stop_recording("window closed") if self.recording else None
            self._end_current("window closed")
            return finished

        try:
            return self.submit(end).result()
        finally:
            self._ops.shutdown(wait=True)

    def test_open(self, name: str) -> str | None:
        """Open and close the rig's device ``name`` on its own through its driver
        (:func:`~vbfe.drivers.registry.check_open`): ``None`` when it opens, else the one-line
        reason. A live view is closed for it (a real device opens once) and reopened after;
        refused while recording."""
        self._not_recording(f"test the {name}")
        live = self.acquisition is not None
        if live:
            self._end_current("device test")
        try:
            return check_open(self.config, name)
        finally:
            if live:
                self.go_live(self.pattern_on, self.board_scene)

    def use_calibration(self, path: Path | None) -> None:
        """Use the calibration file ``path`` (``None``: none) for recordings and the live
        estimate; one made for another image size than the open camera's is refused, as
        ``vbfe live`` refuses it. The live view restarts with it."""
        self._not_recording("change the calibration")
        if path is None:
            self.calibration, self.estimator, self.model_path = None, None, None
            self._restart_live()
            return
        calibration = load_calibration(path)
        if self.rig is not None:
            check_camera_size(self.rig, calibration.image_size, str(path))
        estimator = (
            self._estimator(self.model_path, calibration) if self.model_path is not None else None
        )
        self.calibration, self.calibration_name = calibration, str(path)
        self.estimator = estimator
        self._restart_live()

    def use_model(self, path: Path | None) -> None:
        """Estimate force live with the model file ``path`` (``None``: no estimate) and the
        calibration in use; the live view restarts with it."""
        self._not_recording("change the model")
        if path is None:
            self.estimator, self.model_path, self.model_name = None, None, ""
        else:
            if self.calibration is None:
                raise SessionError(
                    "the estimate needs the calibration it reconstructs with: load one first"
                )
            self.estimator = self._estimator(path, self.calibration)
            self.model_path, self.model_name = path, str(path)
        self._restart_live()

    def set_estimate(self, on: bool) -> None:
        """Run the live estimate (of a loaded model) or not; the live view restarts."""
        self.estimate_on = on
        if self.recording is None:
            self._restart_live()

    def _estimator(self, path: Path, calibration: Calibration) -> FrameEstimator:
        from vbfe.estimate import load_model
        from vbfe.live.run import live_estimator

        return live_estimator(self.config, load_model(path), calibration)

    def _not_recording(self, what: str) -> None:
        if self.recording is not None:
            raise SessionError(f"cannot {what} while {self.recording.name} is recorded: stop it")

    def _restart_live(self) -> None:
        if self.acquisition is not None and self.recording is None:
            self.go_live(self.pattern_on)

    # -- any thread ---------------------------------------------------------------------------
    def mark(self, text: str) -> None:
        """An event mark at the host's now in the running recording."""
        acquisition = self.acquisition
        if self.recording is None or not isinstance(acquisition, Recorder):
            raise SessionError("marks go into a recording: start one first")
        acquisition.sink.mark(text, acquisition.rig.host_now_ns())
        self.marks += 1

    # -- internals ----------------------------------------------------------------------------
    def _options(self) -> RigOptions:
        """As ``vbfe record`` and ``view --live`` run the rig; with the live estimate, as
        ``vbfe live`` (in real time)."""
        estimating = self.estimator is not None and self.estimate_on
        return RigOptions(realtime=True) if estimating else RigOptions()

    def _open_rig(self, options: RigOptions, config: RigConfig | None = None) -> Rig:
        config = config if config is not None else self.config
        self.board_scene = config is not self.config
        self.rig = self._rig_factory(config, options)
        return self.rig

    def _begin(
        self, acquisition: Acquisition, duration_s: float | None = None, estimate: bool = True
    ) -> None:
        acquisition.add(self.latest)
        live = None
        if self.estimator is not None and estimate and self.estimate_on:
            from vbfe.live.run import LiveRun

            live = LiveRun(
                acquisition,
                self.estimator,
                self.model_name,
                max_frame_age_s=self.config.live.max_frame_age_s,
            )
        try:
            (live.start if live is not None else acquisition.start)(duration_s)
        except DeviceError:
            self.device_errors = acquisition.rig.probe()
            raise
        self.device_errors = {}
        self.acquisition, self.live, self._run_error = acquisition, live, None
        self._runner = threading.Thread(
            target=self._run, args=(acquisition,), name="vbfe-console-run", daemon=True
        )
        self._runner.start()

    def _run(self, acquisition: Acquisition) -> None:
        try:
            acquisition.run()
        except Exception as exc:  # noqa: BLE001 - raised by _end_current on the worker
            self._run_error = exc

    def _end_current(self, reason: str) -> AcquisitionStats:
        """Stop the running acquisition (and its estimate); raise what failed in it."""
        acquisition, live, runner = self.acquisition, self.live, self._runner
        if acquisition is None or runner is None:
            return AcquisitionStats()
        acquisition.request_stop(reason)
        runner.join()
        self.acquisition, self.live, self._runner = None, None, None
        error = self._run_error
        if live is not None:
            live.stop(reason)
            if error is None and live.error is not None and isinstance(acquisition, Recorder):
                error = SessionError(live.error)
        if error is not None:
            raise error
        return acquisition.stats
