"""The simulated bench: one traction trial on a silicone hose, seen and measured with known truth.

``SimBench`` owns the true rig, the tissue and its mechanics, the projector's current pattern,
the device clocks and the simulated time; ``camera()``, ``trocar()`` and ``projector()`` hand
out driver-interface devices that share it (see :mod:`vbfe.drivers.sim.devices`).
"""

from __future__ import annotations

import inspect
import math
import threading
import time
from typing import Any, Literal

import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.common.settings import parse_kwargs
from vbfe.drivers.pacing import sleep_until
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.sim.board_scene import BoardScene, board_target
from vbfe.drivers.sim.clocks import DeviceClock, Transport
from vbfe.drivers.sim.devices import SimCamera, SimProjector, SimTrocar
from vbfe.drivers.sim.freehand import FreehandProtocol
from vbfe.drivers.sim.mechanics import TapProtocol, TissueSample, TractionProtocol, Trial
from vbfe.drivers.sim.nuisance import Nuisance
from vbfe.drivers.sim.optics import Optics
from vbfe.drivers.sim.render import StereoRenderer
from vbfe.drivers.sim.rig import StereoRig, default_rig, rig_from_dict, rig_to_dict
from vbfe.drivers.sim.tissue import Plane, Surface, TissueSurface, UniformAlbedo, tissue_texture

SCENES = ("tissue", "plane", "board")
PROTOCOLS = ("traction", "sync", "freehand")
FORCE_RANGE_N = 5.0  # TRF85D measuring range
_STREAMS = (
    "sample",
    "clocks",
    "render",
    "camera_transport",
    "force_transport",
    "force_noise",
    "texture",
    "board",
    "taps",
    "projector",
    "freehand",
)


MAX_PIXELS = 8192 * 8192  # per camera image: larger is a typo, not a camera


class SimBench:
    """A simulated rig: stereo endoscope, projector, trocar and a hose pulled once.

    ``scene`` is ``"tissue"`` (the deforming hose), ``"plane"`` (a flat white plane at the
    working distance, e.g. for pattern checks) or ``"board"`` (a calibration board moved in front
    of the endoscope, see :mod:`vbfe.drivers.sim.board_scene`: ``board_*`` arguments; the
    ``board_poses`` are ``[rx, ry, rz, tx, ty, tz]`` rows, a Rodrigues vector in rad and a
    translation in m, board → left camera; empty: random; ``board_optics`` the camera's optics
    and sensor in room light, :class:`vbfe.drivers.sim.optics.Optics` fields).
    The trocar always follows the protocol. Latencies are the mean (= median, the jitter being
    symmetric) host arrival delays of each stream; the reader's clock fits map each stream to its
    median arrival, so ``image_latency_ms − force_latency_ms`` is the offset a synchronisation
    tool must find. Time starts (true time 0, the trial's start) when the first device is
    opened. ``pixel_aspect`` (fx / fy) and ``principal_offsets_px`` ([[left dx, dy], [right dx,
    dy]]) shape the endoscope's cameras (:func:`~vbfe.drivers.sim.rig.default_rig`).

    ``protocol = "sync"`` replaces the pull by the sync protocol's taps (``sync_taps`` in
    ``sync_duration_s``, peak about ``tap_force_n``); ``protocol = "freehand"`` by a
    hand-guided trial of ``freehand_duration_s`` (:mod:`vbfe.drivers.sim.freehand`: varying
    speed, pauses, partial releases, holds at random levels up to ``target_force_n``) on a
    stiffness drawn per seed, log-uniform in ``freehand_stiffness_n_per_m`` (which replaces
    ``stiffness_n_per_m``). Frames integrate the projector's light
    over ``exposure_ms`` (rows offset by ``line_time_us``: rolling shutter); a pattern lights
    the scene ``projector_latency_ms`` after its command, so a flash's true latency on the
    frames' clock is ``image_latency_ms + projector_latency_ms``.
    """

    def __init__(
        self,
        rig: StereoRig | None = None,
        seed: int = 0,
        width: int = 640,
        height: int = 360,
        fps: float = 30.0,
        scene: str = "tissue",
        stiffness_n_per_m: float = 80.0,
        pull_speed_m_per_s: float = 0.005,
        target_force_n: float = 3.0,
        rest_s: float = 0.5,
        hold_s: float = 3.0,
        image_latency_ms: float = 45.0,
        force_latency_ms: float = 8.0,
        image_jitter_ms: float = 1.0,
        force_jitter_ms: float = 0.2,
        camera_drift_ppm: float = 40.0,
        trocar_drift_ppm: float = -60.0,
        trocar_rate_hz: float = 1000.0,
        force_noise_n: float = 0.03,
        force_resolution_n: float = 0.01,
        noise_sigma: float = 1.0,
        ambient: float = 0.15,
        textured: bool = False,
        distortion: bool = False,
        baseline_m: float = 0.004,
        pixel_aspect: float = 1.0,
        principal_offsets_px: list[list[float]] | None = None,
        working_distance_m: float = 0.06,
        deformation_scale: float = 0.15,
        realtime: bool = False,
        board: str = "charuco",
        board_squares_x: int = 9,
        board_squares_y: int = 7,
        board_square_mm: float = 3.0,
        board_marker_mm: float = 2.2,
        board_dictionary: str = "DICT_5X5_100",
        board_legacy: bool = False,
        board_poses: list[list[float]] | None = None,
        board_hold_s: float = 0.0,
        board_p_still: float = 0.25,
        board_p_blur: float = 0.15,
        board_blur_px: int = 5,
        board_distance_mm: tuple[float, float] = (30.0, 70.0),
        board_max_tilt_deg: float = 35.0,
        board_in_projector: bool = False,
        board_optics: dict[str, float] | None = None,
        albedo_bgr: tuple[float, float, float] | None = None,
        subsurface_blur_mm: float = 0.0,
        specular: float = 0.0,
        crosstalk: float = 0.0,
        projector_gamma: float = 1.0,
        vignetting: float = 0.0,
        motion_blur_exposure_ms: float = 0.0,
        protocol: Literal["traction", "sync", "freehand"] = "traction",
        sync_taps: int = 20,
        sync_duration_s: float = 20.0,
        tap_force_n: float = 1.0,
        freehand_duration_s: float = 15.0,
        freehand_stiffness_n_per_m: tuple[float, float] = (70.0, 95.0),
        projector_latency_ms: float = 0.0,
        exposure_ms: float = 0.0,
        line_time_us: float = 0.0,
    ) -> None:
        if scene not in SCENES:
            raise DeviceError(f"[bench] scene must be one of {SCENES}, got {scene!r}")
        if fps <= 0 or trocar_rate_hz <= 0:
            raise DeviceError("[bench] fps and trocar_rate_hz must be positive")
        if width <= 0 or height <= 0 or width * height > MAX_PIXELS:
            raise DeviceError(
                f"[bench] width x height = {width}x{height}: give positive sizes "
                f"of at most {MAX_PIXELS // 10**6} megapixels"
            )
        if protocol not in PROTOCOLS:
            raise DeviceError(f"[bench] protocol must be one of {PROTOCOLS}, got {protocol!r}")
        if protocol == "freehand" and not (
            0 < freehand_stiffness_n_per_m[0] <= freehand_stiffness_n_per_m[1]
            and freehand_duration_s >= 2.0
            and target_force_n >= 1.0
        ):
            raise DeviceError(
                "[bench] freehand protocol: freehand_stiffness_n_per_m must be "
                "[low, high] with 0 < low <= high, freehand_duration_s >= 2 and "
                "target_force_n >= 1"
            )
        if not 0 <= exposure_ms <= 1e3 / fps or projector_latency_ms < 0 or line_time_us < 0:
            raise DeviceError(
                "[bench] exposure_ms must be within [0, 1000/fps]; "
                "projector_latency_ms and line_time_us must not be negative"
            )
        if (
            image_latency_ms + projector_latency_ms
            < (exposure_ms + line_time_us * 1e-3 * height) / 2 + 3 * image_jitter_ms
        ):
            raise DeviceError(
                "[bench] image_latency_ms + projector_latency_ms must exceed half the "
                "exposure and readout plus 3x image_jitter_ms (a pattern must not "
                "light frames that have already arrived)"
            )
        if image_latency_ms < 3 * image_jitter_ms or force_latency_ms < 3 * force_jitter_ms:
            raise DeviceError(
                "[bench] each latency must be at least 3x its jitter "
                "(image_latency_ms/image_jitter_ms, force_latency_ms/force_jitter_ms)"
            )
        self._params = {
            name: value for name, value in locals().items() if name not in ("self", "rig")
        }
        for key, value in {
            "stiffness_n_per_m": stiffness_n_per_m,
            "pull_speed_m_per_s": pull_speed_m_per_s,
            "target_force_n": target_force_n,
            "tap_force_n": tap_force_n,
            "sync_duration_s": sync_duration_s,
            "baseline_m": baseline_m,
            "working_distance_m": working_distance_m,
        }.items():
            if not value > 0:
                raise DeviceError(f"[bench] {key} = {value} must be positive")
        for key, value in {
            "rest_s": rest_s,
            "hold_s": hold_s,
            "noise_sigma": noise_sigma,
            "force_noise_n": force_noise_n,
            "ambient": ambient,
            "force_resolution_n": force_resolution_n,
        }.items():
            if value < 0:
                raise DeviceError(f"[bench] {key} = {value} must not be negative")
        if not 0.5 <= pixel_aspect <= 2.0:
            raise DeviceError(f"[bench] pixel_aspect = {pixel_aspect} must be within [0.5, 2]")
        offsets = None
        if principal_offsets_px is not None:
            if np.shape(principal_offsets_px) != (2, 2):
                raise DeviceError(
                    "[bench] principal_offsets_px must be [[left dx, dy], [right dx, dy]] (px)"
                )
            (lx, ly), (rx, ry) = principal_offsets_px
            offsets = ((float(lx), float(ly)), (float(rx), float(ry)))
        self.rig = (
            rig
            if rig is not None
            else default_rig(
                width,
                height,
                baseline_m,
                working_distance_m,
                distortion,
                pixel_aspect,
                offsets,
            )
        )
        self._params.update(width=self.rig.left.width, height=self.rig.left.height)
        self.seed, self.fps, self.scene, self.realtime = seed, float(fps), scene, realtime
        self.trocar_rate_hz = float(trocar_rate_hz)
        self.force_noise_n, self.force_resolution_n = force_noise_n, force_resolution_n
        self.force_range_n = FORCE_RANGE_N
        self.frame_period_ns = int(round(1e9 / fps))
        self.sample_period_ns = int(round(1e9 / trocar_rate_hz))
        rngs = dict(
            zip(
                _STREAMS,
                (
                    np.random.default_rng(s)
                    for s in np.random.SeedSequence(seed).spawn(len(_STREAMS))
                ),
                strict=False,
            )
        )
        self._force_rng = rngs["force_noise"]
        motion: TapProtocol | FreehandProtocol | TractionProtocol
        if protocol == "sync":
            motion = TapProtocol.random(
                rngs["taps"], sync_taps, sync_duration_s, stiffness_n_per_m, tap_force_n
            )
        elif protocol == "freehand":
            motion = _freehand(
                rngs["freehand"],
                freehand_stiffness_n_per_m,
                freehand_duration_s,
                target_force_n,
                rest_s,
            )
        else:
            motion = TractionProtocol(
                stiffness_n_per_m, pull_speed_m_per_s, target_force_n, rest_s, hold_s
            )
        self._board = None
        if scene == "board":
            target = board_target(
                board,
                board_squares_x,
                board_squares_y,
                board_square_mm,
                board_marker_mm,
                board_dictionary,
                board_legacy,
            )
            if any(len(p) != 6 for p in (board_poses or [])):
                raise DeviceError("[bench] board_poses must be rows [rx, ry, rz, tx, ty, tz]")
            poses = [
                (np.asarray(p[:3], np.float64), np.asarray(p[3:], np.float64))
                for p in (board_poses or [])
            ]
            self._board = BoardScene(
                self.rig,
                target,
                rngs["board"],
                self.frame_period_ns,
                poses,
                board_hold_s,
                board_p_still,
                board_p_blur,
                board_blur_px,
                (board_distance_mm[0] * 1e-3, board_distance_mm[1] * 1e-3),
                board_max_tilt_deg,
                board_in_projector,
                Optics.from_table(board_optics),
            )
        self.trial = Trial(
            motion, TissueSample.random(rngs["sample"], working_distance_m), deformation_scale
        )
        b, g, r = UniformAlbedo().bgr if albedo_bgr is None else albedo_bgr
        tint = (float(b), float(g), float(r))
        albedo = tissue_texture(rngs["texture"], tint_bgr=tint) if textured else UniformAlbedo(tint)
        self._tissue = TissueSurface(distance_m=working_distance_m, texture=albedo)
        self._plane = Plane(
            np.eye(3),
            np.array([0.0, 0.0, working_distance_m]),
            texture=UniformAlbedo((1.0, 1.0, 1.0)),
        )
        clock_rng = rngs["clocks"]
        self.camera_clock = DeviceClock(int(clock_rng.integers(10**9, 10**12)), camera_drift_ppm)
        self.trocar_clock = DeviceClock(
            int(clock_rng.integers(10**9, 10**12)), trocar_drift_ppm, tick_ns=1000
        )
        # not in real time the host clock is simulated too: its epoch comes from the seed, so
        # two recordings of one bench hold the same host timestamps
        self._sim_host_epoch_ns = int(clock_rng.integers(10**9, 10**12))
        self.image_latency_ns = int(round(image_latency_ms * 1e6))
        self.force_latency_ns = int(round(force_latency_ms * 1e6))
        self.camera_transport = Transport(
            self.image_latency_ns, image_jitter_ms * 1e6, rngs["camera_transport"]
        )
        self.force_transport = Transport(
            self.force_latency_ns, force_jitter_ms * 1e6, rngs["force_transport"]
        )
        self.renderer = StereoRenderer(
            self.rig,
            ambient=ambient,
            noise_sigma=noise_sigma,
            rng=rngs["render"],
            nuisance=self._nuisance(
                subsurface_blur_mm,
                specular,
                crosstalk,
                projector_gamma,
                vignetting,
                pull_speed_m_per_s * motion_blur_exposure_ms * 1e-3,
                working_distance_m,
            ),
        )
        self.projector_latency_ns = int(round(projector_latency_ms * 1e6))
        self.exposure_ns = int(round(exposure_ms * 1e6))
        self.line_time_ns = line_time_us * 1e3
        self._projector_rng = rngs["projector"]
        self._light: list[tuple[int, np.ndarray]] = []  # (true ns it lights the scene, pattern)
        self._lit: np.ndarray | None = None  # the pattern the renderer holds
        self._time = threading.Condition()
        self._now_host_ns = 0  # newest frame's host arrival, relative to host_epoch_ns
        self._open_devices: set[int] = set()
        self._camera_open = False
        self.host_epoch_ns = 0

    def _nuisance(
        self,
        subsurface_blur_mm: float,
        specular: float,
        crosstalk: float,
        projector_gamma: float,
        vignetting: float,
        travel_m: float,
        distance_m: float,
    ) -> Nuisance:
        """The tissue/optics nuisances; motion blur is the grasp's travel during one exposure
        at the pull speed, seen at the working distance (an upper bound for the whole view)."""
        dx, dy, _ = self.trial.sample.pull_direction
        return Nuisance(
            subsurface_blur_mm=subsurface_blur_mm,
            specular=specular,
            crosstalk=crosstalk,
            projector_gamma=projector_gamma,
            vignetting=vignetting,
            motion_blur_px=travel_m * self.rig.left.f / distance_m,
            motion_blur_deg=math.degrees(math.atan2(dy, dx)),
        )

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def from_config(cls, table: dict[str, Any]) -> SimBench:
        """A bench from the rig config's ``[bench]`` table (keys are constructor arguments)."""
        return cls(**parse_kwargs(cls, table, "bench", skip=("rig",)))

    def describe(self) -> dict[str, Any]:
        """JSON-able description: constructor arguments, the true rig and the trial drawn."""
        return {**self._params, "rig": rig_to_dict(self.rig), "trial": self.trial.describe()}

    @classmethod
    def from_description(cls, description: dict[str, Any]) -> SimBench:
        """Rebuild the bench :meth:`describe` described (same seed: same trial and noise)."""
        params = {k: v for k, v in description.items() if k not in ("rig", "trial")}
        rig = rig_from_dict(description["rig"]) if "rig" in description else None
        return cls(rig=rig, **params)

    @classmethod
    def duration_from_config(cls, table: dict[str, Any]) -> float:
        """How long the trial a ``[bench]`` table sets lasts, without building the bench."""
        defaults = inspect.signature(cls.__init__).parameters
        value = {k: table.get(k, p.default) for k, p in defaults.items() if k != "self"}
        if value["protocol"] == "sync":
            return float(value["sync_duration_s"])
        if value["protocol"] == "freehand":
            rng = np.random.default_rng(
                np.random.SeedSequence(value["seed"]).spawn(len(_STREAMS))[
                    _STREAMS.index("freehand")
                ]
            )
            return _freehand(
                rng,
                value["freehand_stiffness_n_per_m"],
                value["freehand_duration_s"],
                value["target_force_n"],
                value["rest_s"],
            ).duration_s()
        return TractionProtocol(
            *(
                value[k]
                for k in (
                    "stiffness_n_per_m",
                    "pull_speed_m_per_s",
                    "target_force_n",
                    "rest_s",
                    "hold_s",
                )
            )
        ).duration_s()

    def conditions(self) -> dict[str, Any]:
        """Experimental conditions of the trial, for session metadata."""
        p, s = self.trial.protocol, self.trial.sample
        run = {"scene": self.scene, "seed": self.seed, "simulated": True}
        if isinstance(p, TapProtocol):
            return {
                "protocol": "sync",
                "stiffness_n_per_m": p.stiffness_n_per_m,
                "taps": len(p.tap_times_s),
                "thickness_m": s.thickness_m,
                **run,
            }
        grasp = {
            "target_force_n": p.target_force_n,
            "thickness_m": s.thickness_m,
            "contact_m": list(s.contact_m),
            "pull_direction": list(s.pull_direction),
            **run,
        }
        if isinstance(p, FreehandProtocol):
            return {
                "protocol": "freehand",
                "label": f"freehand {p.stiffness_n_per_m:.0f} N/m",
                "stiffness_n_per_m": p.stiffness_n_per_m,
                **grasp,
            }
        return {
            "stiffness_n_per_m": p.stiffness_n_per_m,
            "pull_speed_m_per_s": p.pull_speed_m_per_s,
            **grasp,
        }

    def duration_s(self) -> float:
        """Length of one traction trial (rest, pull until the target force, hold), of the
        freehand trial or of the sync protocol session."""
        return self.trial.protocol.duration_s()

    # -- devices --------------------------------------------------------------------------
    def camera(self, **options: Any) -> SimCamera:
        """The simulated stereo endoscope."""
        return SimCamera(self, **options)

    def trocar(self, **options: Any) -> SimTrocar:
        """The simulated force trocar."""
        return SimTrocar(self, **options)

    def projector(self, **options: Any) -> SimProjector:
        """The simulated projector."""
        return SimProjector(self, **options)

    def device_opened(self, device: object, drives_time: bool = False) -> None:
        """Called by devices on open; the first open starts the clock. The camera
        ``drives_time`` (its frames move the simulated host clock)."""
        with self._time:
            if not self._open_devices:
                self.host_epoch_ns = (
                    time.monotonic_ns() if self.realtime else self._sim_host_epoch_ns
                )
            self._open_devices.add(id(device))
            self._camera_open |= drives_time

    def device_closed(self, device: object, drives_time: bool = False) -> None:
        """Called by devices on close; wakes readers waiting for the camera."""
        with self._time:
            self._open_devices.discard(id(device))
            if drives_time:
                self._camera_open = False
            self._time.notify_all()

    # -- simulated time -------------------------------------------------------------------
    def host_now_ns(self) -> int:
        """The host clock: real monotonic time, or the simulated one when not in real time."""
        if self.realtime:
            return time.monotonic_ns()
        return self.host_epoch_ns + self._now_host_ns

    def advance_to(self, host_ns: int) -> None:
        """Move the simulated host clock forward (relative ns; the camera does this per frame)."""
        with self._time:
            self._now_host_ns = max(self._now_host_ns, int(host_ns))
            self._time.notify_all()

    def wait_until(self, host_ns: int, timeout_s: float) -> bool:
        """Block until the host clock reaches ``host_ns`` (relative), the arrival of a sample.

        Not in real time, the camera's frames drive the host clock; with no camera open the
        reader's own samples do."""
        if self.realtime:
            return sleep_until(self.host_epoch_ns + host_ns, timeout_s)
        with self._time:
            if not self._camera_open:  # nobody drives time: the reader does
                self._now_host_ns = max(self._now_host_ns, host_ns)
                return True
            return self._time.wait_for(
                lambda: self._now_host_ns >= host_ns or not self._camera_open, timeout_s
            )

    def frames_due(self) -> int:
        """Index of the newest frame that has arrived at the host (real-time mode)."""
        elapsed = time.monotonic_ns() - self.host_epoch_ns - self.image_latency_ns
        return math.floor(elapsed / self.frame_period_ns)

    def frame_arrival_host_ns(self, k: int) -> int:
        """Nominal host arrival time of frame ``k`` (real-time mode)."""
        return self.host_epoch_ns + k * self.frame_period_ns + self.image_latency_ns

    # -- what the devices see and measure -------------------------------------------------
    def show_pattern(self, pattern_bgr: np.ndarray) -> int:
        """A projector command at the host's now: the pattern lights the scene
        ``projector_latency_ms`` later. Returns the command's host time (absolute ns).

        Not in real time the host clock stands at the newest frame's arrival between frames, so
        the command is placed uniformly within the next frame period (a real host issues it at
        any phase of the camera's frames). With ``projector_latency_ms = 0`` the projector is
        ideal: every frame rendered after the command sees the pattern."""
        with self._time:
            now = self.host_now_ns() - self.host_epoch_ns
            if self.projector_latency_ns == 0:
                self._light = [(-(2**62), pattern_bgr)]
                return now + self.host_epoch_ns
            if not self.realtime:
                now += int(self._projector_rng.integers(0, self.frame_period_ns))
            self._light.append((now + self.projector_latency_ns, pattern_bgr))
            return now + self.host_epoch_ns

    def _exposure(self, true_ns: int) -> list[tuple[np.ndarray, np.ndarray | float]]:
        """The patterns lighting frame ``true_ns`` and their share of each row's exposure
        (window centred on the frame's time; rolling shutter: rows offset by the line time)."""
        with self._time:
            light = list(self._light)
        if not light or light[0][0] > true_ns - self.exposure_ns // 2 - self._readout_ns():
            default = make_pattern(self.rig.projector.width, self.rig.projector.height)
            light.insert(0, (-(2**62), default))
            with self._time:
                self._light.insert(0, light[0])
        rows = (
            np.arange(self.rig.left.height) - (self.rig.left.height - 1) / 2
        ) * self.line_time_ns
        start = true_ns + rows - self.exposure_ns / 2
        end = start + self.exposure_ns
        shares = []
        for (on, pattern), (off, _) in zip(light, light[1:] + [(2**62, None)], strict=False):
            if self.exposure_ns > 0:
                share = (
                    np.clip(np.minimum(end, off) - np.maximum(start, on), 0, None)
                    / self.exposure_ns
                )
            else:
                share = ((start >= on) & (start < off)).astype(np.float64)
            if share.any():
                shares.append((pattern, share[0] if self.line_time_ns == 0 else share))
        return shares

    def _readout_ns(self) -> float:
        return self.line_time_ns * self.rig.left.height / 2

    def surface_at(self, true_ns: int) -> Surface:
        """The scene's surface at true time ``true_ns``."""
        if self.scene == "plane":
            return self._plane
        if self._board is not None:
            return self._board.surface_at(true_ns)
        load, _, _ = self.trial.at(true_ns / 1e9)
        return self._tissue.with_load(load)

    def render_frame(self, true_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right images at true time ``true_ns``: the scene at that instant, lit by
        the patterns of the exposure window (a pattern change mid-exposure gives a mix).

        Until the projector shows something, the tissue is lit by the structured-light pattern
        and the board by room light."""
        if self._board is not None:
            return self._board.render(true_ns, self._lit_renderer(true_ns))
        surface = self.surface_at(true_ns)
        views = []
        for pattern, share in self._exposure(true_ns):
            self._set_lit(pattern)
            views.append((self.renderer.render(surface), share))
        if len(views) == 1:
            return views[0][0]
        left, right = (_mix([(pair[eye], w) for pair, w in views]) for eye in range(2))
        return left, right

    def _set_lit(self, pattern: np.ndarray) -> None:
        if pattern is not self._lit:
            self.renderer.set_pattern(pattern, distance_m=self._tissue.distance_m)
            self._lit = pattern

    def _lit_renderer(self, true_ns: int) -> StereoRenderer | None:
        """The renderer lit by the newest pattern shown by ``true_ns`` (None: room light)."""
        with self._time:
            shown = [pattern for on, pattern in self._light if on <= true_ns]
        if not shown:
            return None
        self._set_lit(shown[-1])
        return self.renderer

    def trocar_block(self, first: int, n: int) -> dict[str, np.ndarray]:
        """Trocar samples ``first … first+n−1``: true/device/host (relative) ns and force (N)."""
        true = (first + np.arange(n, dtype=np.int64)) * self.sample_period_ns
        force = self.trial.forces(true / 1e9)
        force = force + self._force_rng.normal(0.0, self.force_noise_n, force.shape)
        force = np.clip(
            np.round(force / self.force_resolution_n) * self.force_resolution_n,
            -self.force_range_n,
            self.force_range_n,
        )
        return {
            "true": true,
            "device": self.trocar_clock.device_ns(true),
            "host": self.force_transport.host_ns(true),
            "force": force,
        }

    # -- ground truth ---------------------------------------------------------------------
    def session_truth(self, frame_t_device_ns: np.ndarray) -> dict[str, np.ndarray]:
        """Per-frame truth for camera frames stamped ``frame_t_device_ns`` (camera clock).

        ``force_n`` (n×3, left-camera axes) and ``force_magnitude_n`` at the frame's true time;
        ``frame_t_true_ns``; ``frame_t_host_nominal_ns`` (true + median image latency: the
        reader's clock fit maps each stream to its median arrival); ``trocar_t_device_ns`` (the
        trocar clock at that instant); ``image_minus_force_host_offset_ns`` (difference of the
        median latencies — the jitter is symmetric, so of the nominal ones: the offset left
        between the clock-fitted streams, which a sync tool must find);
        ``grasper_displacement_m``; ``phase`` (0 rest, 1 pull, 2 hold).
        """
        true_ns = self.camera_clock.true_ns(np.asarray(frame_t_device_ns, np.int64))
        u, force, phase = self.trial.protocol.state(true_ns / 1e9)
        n = len(true_ns)
        return {
            "frame_t_true_ns": true_ns,
            "frame_t_host_nominal_ns": self.host_epoch_ns + true_ns + self.image_latency_ns,
            "trocar_t_device_ns": self.trocar_clock.device_ns(true_ns),
            "force_n": self.trial.forces(true_ns / 1e9),
            "force_magnitude_n": force,
            "grasper_displacement_m": u,
            "phase": phase.astype(np.int8),
            "image_minus_force_host_offset_ns": np.full(
                n, self.image_latency_ns - self.force_latency_ns, np.int64
            ),
        }

    def render_truth(self, frame_t_device_ns: int) -> dict[str, np.ndarray]:
        """Exact left-view truth of one frame: ``depth_left_m``, ``disparity_left_px``,
        ``proj_uv_left``, ``valid_left`` (see :meth:`StereoRenderer.truth`)."""
        true_ns = int(self.camera_clock.true_ns(int(frame_t_device_ns)))
        return self.renderer.truth(self.surface_at(true_ns))


def _freehand(
    rng: np.random.Generator,
    stiffness_range: tuple[float, float],
    duration_s: float,
    target_force_n: float,
    rest_s: float,
) -> FreehandProtocol:
    """The freehand trial of a seed: stiffness log-uniform in ``stiffness_range``, then steps."""
    stiffness = float(np.exp(rng.uniform(*np.log(stiffness_range))))
    return FreehandProtocol.random(rng, stiffness, duration_s, target_force_n, rest_s)


def _mix(parts: list[tuple[np.ndarray, np.ndarray | float]]) -> np.ndarray:
    """Weighted sum of images (per-row weights or one weight each), as ``uint8``."""
    total = sum(
        np.asarray(w, np.float32).reshape(-1, 1, 1) * image.astype(np.float32) for image, w in parts
    )
    return np.clip(total + 0.5, 0, 255).astype(np.uint8)
