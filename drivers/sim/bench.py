"""The simulated bench: one traction trial on a silicone hose, seen and measured with known truth.

``SimBench`` owns the true rig, the tissue and its mechanics, the projector's current pattern,
the device clocks and the simulated time; ``camera()``, ``trocar()`` and ``projector()`` hand
out driver-interface devices that share it (see :mod:`vbfe.drivers.sim.devices`).
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np

from vbfe.drivers.errors import DeviceError
from vbfe.drivers.sim.clocks import DeviceClock, Transport
from vbfe.drivers.sim.devices import FORCE_RANGE_N, SimCamera, SimProjector, SimTrocar
from vbfe.drivers.sim.mechanics import TissueSample, TractionProtocol, Trial
from vbfe.drivers.sim.render import StereoRenderer
from vbfe.drivers.sim.rig import StereoRig, default_rig, rig_from_dict, rig_to_dict
from vbfe.drivers.sim.tissue import Plane, Surface, TissueSurface, UniformAlbedo, tissue_texture
from vbfe.settings import parse_kwargs

SCENES = ("tissue", "plane")
_STREAMS = ("sample", "clocks", "render", "camera_transport", "force_transport", "force_noise",
            "texture")


class SimBench:
    """A simulated rig: stereo endoscope, projector, trocar and a hose pulled once.

    ``scene`` is ``"tissue"`` (the deforming hose) or ``"plane"`` (a flat white plane at the
    working distance, e.g. for pattern checks; the trocar still follows the protocol). Latencies
    are the mean (= median, the jitter being symmetric) host arrival delays of each stream; the
    reader's clock fits map each stream to its median arrival, so
    ``image_latency_ms − force_latency_ms`` is the offset a synchronisation tool must find. Time starts (true time 0, the trial's start)
    when the first device is opened.
    """

    def __init__(self, rig: StereoRig | None = None, seed: int = 0, width: int = 640,
                 height: int = 360, fps: float = 30.0, scene: str = "tissue",
                 stiffness_n_per_m: float = 80.0, pull_speed_m_per_s: float = 0.005,
                 target_force_n: float = 3.0, rest_s: float = 0.5, hold_s: float = 3.0,
                 image_latency_ms: float = 45.0, force_latency_ms: float = 8.0,
                 image_jitter_ms: float = 1.0, force_jitter_ms: float = 0.2,
                 camera_drift_ppm: float = 40.0, trocar_drift_ppm: float = -60.0,
                 trocar_rate_hz: float = 1000.0, force_noise_n: float = 0.03,
                 force_resolution_n: float = 0.01, noise_sigma: float = 1.0,
                 ambient: float = 0.15, textured: bool = False, distortion: bool = False,
                 baseline_m: float = 0.004, working_distance_m: float = 0.06,
                 deformation_scale: float = 0.15, realtime: bool = False) -> None:
        if scene not in SCENES:
            raise DeviceError(f"[bench] scene must be one of {SCENES}, got {scene!r}")
        if width <= 0 or height <= 0:
            raise DeviceError(f"[bench] width and height must be positive, got {width}x{height}")
        if fps <= 0 or trocar_rate_hz <= 0:
            raise DeviceError("[bench] fps and trocar_rate_hz must be positive")
        if image_latency_ms < 3 * image_jitter_ms or force_latency_ms < 3 * force_jitter_ms:
            raise DeviceError("[bench] each latency must be at least 3x its jitter "
                              "(image_latency_ms/image_jitter_ms, force_latency_ms/force_jitter_ms)")
        self._params = {name: value for name, value in locals().items()
                        if name not in ("self", "rig")}
        self.rig = rig if rig is not None else default_rig(width, height, baseline_m,
                                                           working_distance_m, distortion)
        self._params.update(width=self.rig.left.width, height=self.rig.left.height)
        self.seed, self.fps, self.scene, self.realtime = seed, float(fps), scene, realtime
        self.trocar_rate_hz = float(trocar_rate_hz)
        self.force_noise_n, self.force_resolution_n = force_noise_n, force_resolution_n
        self.frame_period_ns = int(round(1e9 / fps))
        self.sample_period_ns = int(round(1e9 / trocar_rate_hz))
        rngs = dict(zip(_STREAMS, (np.random.default_rng(s) for s in
                                   np.random.SeedSequence(seed).spawn(len(_STREAMS)))))
        self._force_rng = rngs["force_noise"]
        protocol = TractionProtocol(stiffness_n_per_m, pull_speed_m_per_s, target_force_n,
                                    rest_s, hold_s)
        self.trial = Trial(protocol, TissueSample.random(rngs["sample"], working_distance_m),
                           deformation_scale)
        albedo = tissue_texture(rngs["texture"]) if textured else UniformAlbedo()
        self._tissue = TissueSurface(distance_m=working_distance_m, texture=albedo)
        self._plane = Plane(np.eye(3), np.array([0.0, 0.0, working_distance_m]),
                            texture=UniformAlbedo((1.0, 1.0, 1.0)))
        clock_rng = rngs["clocks"]
        self.camera_clock = DeviceClock(int(clock_rng.integers(10**9, 10**12)), camera_drift_ppm)
        self.trocar_clock = DeviceClock(int(clock_rng.integers(10**9, 10**12)), trocar_drift_ppm,
                                        tick_ns=1000)
        self.image_latency_ns = int(round(image_latency_ms * 1e6))
        self.force_latency_ns = int(round(force_latency_ms * 1e6))
        self.camera_transport = Transport(self.image_latency_ns, image_jitter_ms * 1e6,
                                          rngs["camera_transport"])
        self.force_transport = Transport(self.force_latency_ns, force_jitter_ms * 1e6,
                                         rngs["force_transport"])
        self.renderer = StereoRenderer(self.rig, ambient=ambient, noise_sigma=noise_sigma,
                                       rng=rngs["render"])
        self._pattern_shown = False
        self._time = threading.Condition()
        self._now_host_ns = 0  # newest frame's host arrival, relative to host_epoch_ns
        self._open_devices: set[int] = set()
        self._camera_open = False
        self.host_epoch_ns = 0

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def from_config(cls, table: dict[str, Any]) -> "SimBench":
        """A bench from the rig config's ``[bench]`` table (keys are constructor arguments)."""
        return cls(**parse_kwargs(cls, table, "bench", skip=("rig",)))

    def describe(self) -> dict[str, Any]:
        """JSON-able description: constructor arguments, the true rig and the trial drawn."""
        return {**self._params, "rig": rig_to_dict(self.rig), "trial": self.trial.describe()}

    @classmethod
    def from_description(cls, description: dict[str, Any]) -> "SimBench":
        """Rebuild the bench :meth:`describe` described (same seed: same trial and noise)."""
        params = {k: v for k, v in description.items() if k not in ("rig", "trial")}
        rig = rig_from_dict(description["rig"]) if "rig" in description else None
        return cls(rig=rig, **params)

    def conditions(self) -> dict[str, Any]:
        """Experimental conditions of the trial, for session metadata."""
        p, s = self.trial.protocol, self.trial.sample
        return {"stiffness_n_per_m": p.stiffness_n_per_m, "pull_speed_m_per_s": p.pull_speed_m_per_s,
                "target_force_n": p.target_force_n, "thickness_m": s.thickness_m,
                "contact_m": list(s.contact_m), "pull_direction": list(s.pull_direction),
                "scene": self.scene, "seed": self.seed, "simulated": True}

    def duration_s(self) -> float:
        """Length of one traction trial (rest, pull until the target force, hold)."""
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

    def device_opened(self, device: object) -> None:
        """Called by devices on open; the first open starts the clock."""
        with self._time:
            if not self._open_devices:
                self.host_epoch_ns = time.monotonic_ns()
            self._open_devices.add(id(device))
            self._camera_open |= isinstance(device, SimCamera)

    def device_closed(self, device: object) -> None:
        """Called by devices on close; wakes readers waiting for the camera."""
        with self._time:
            self._open_devices.discard(id(device))
            if isinstance(device, SimCamera):
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
            wait_s = (self.host_epoch_ns + host_ns - time.monotonic_ns()) / 1e9
            if wait_s > timeout_s:
                time.sleep(timeout_s)
                return False
            time.sleep(max(wait_s, 0.0))
            return True
        with self._time:
            if not self._camera_open:  # nobody drives time: the reader does
                self._now_host_ns = max(self._now_host_ns, host_ns)
                return True
            return self._time.wait_for(lambda: self._now_host_ns >= host_ns
                                       or not self._camera_open, timeout_s)

    def frames_due(self) -> int:
        """Index of the newest frame that has arrived at the host (real-time mode)."""
        elapsed = time.monotonic_ns() - self.host_epoch_ns - self.image_latency_ns
        return math.floor(elapsed / self.frame_period_ns)

    def frame_arrival_host_ns(self, k: int) -> int:
        """Nominal host arrival time of frame ``k`` (real-time mode)."""
        return self.host_epoch_ns + k * self.frame_period_ns + self.image_latency_ns

    # -- what the devices see and measure -------------------------------------------------
    def show_pattern(self, pattern_bgr: np.ndarray) -> None:
        """Light the scene with a projector image from now on."""
        self.renderer.set_pattern(pattern_bgr, distance_m=self._tissue.distance_m)
        self._pattern_shown = True

    def surface_at(self, true_ns: int) -> Surface:
        """The scene's surface at true time ``true_ns``."""
        if self.scene == "plane":
            return self._plane
        load, _, _ = self.trial.at(true_ns / 1e9)
        return self._tissue.with_load(load)

    def render_frame(self, true_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right images at true time ``true_ns``."""
        if not self._pattern_shown:
            from vbfe.recon.pattern import make_pattern

            self.show_pattern(make_pattern(self.rig.projector.width, self.rig.projector.height))
        return self.renderer.render(self.surface_at(true_ns))

    def trocar_block(self, first: int, n: int) -> dict[str, np.ndarray]:
        """Trocar samples ``first … first+n−1``: true/device/host (relative) ns and force (N)."""
        true = (first + np.arange(n, dtype=np.int64)) * self.sample_period_ns
        force = self.trial.forces(true / 1e9)
        force = force + self._force_rng.normal(0.0, self.force_noise_n, force.shape)
        force = np.clip(np.round(force / self.force_resolution_n) * self.force_resolution_n,
                        -FORCE_RANGE_N, FORCE_RANGE_N)
        return {"true": true, "device": self.trocar_clock.device_ns(true),
                "host": self.force_transport.host_ns(true), "force": force}

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
                n, self.image_latency_ns - self.force_latency_ns, np.int64),
        }

    def render_truth(self, frame_t_device_ns: int) -> dict[str, np.ndarray]:
        """Exact left-view truth of one frame: ``depth_left_m``, ``disparity_left_px``,
        ``proj_uv_left``, ``valid_left`` (see :meth:`StereoRenderer.truth`)."""
        true_ns = int(self.camera_clock.true_ns(int(frame_t_device_ns)))
        return self.renderer.truth(self.surface_at(true_ns))
