"""Synthetic devices for the acquire tests (no tests here).

A moving bar whose position follows a force profile is seen by a stereo camera; a force
sensor reads the same profile. Each device has its own clock (offset, drift) and its own
transport latency onto the host clock, so synchronization has something to find. Devices run
paced at ``speed`` times real time.
"""

from __future__ import annotations

import time

import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.pacing import sleep_until
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.rig import Rig
from vbfe.drivers.samples import ForceSample, StereoFrame
from vbfe.drivers.trocar.base import ForceSensor


def force_profile(t_s: np.ndarray | float) -> np.ndarray:
    """A pull-and-hold-like force (N) with irregular ramps, so its changes have a unique lag."""
    t = np.asarray(t_s, dtype=np.float64)
    bumps = [
        (0.4, 0.25, 1.0),
        (1.3, 0.15, -0.6),
        (2.1, 0.3, 1.4),
        (3.0, 0.1, -0.9),
        (3.7, 0.2, 0.8),
        (4.5, 0.35, -1.2),
        (5.4, 0.12, 0.7),
        (6.1, 0.25, -0.5),
    ]
    fz = sum(a / (1 + np.exp(-(t - t0) / w * 4)) for t0, w, a in bumps)
    return np.stack([0.1 * fz, np.zeros_like(t), fz], axis=-1)


def bar_image(x: float, width: int, height: int) -> np.ndarray:
    """A bright anti-aliased vertical bar centred at column ``x`` on a dark background (BGR)."""
    cols = np.arange(width, dtype=np.float64)
    row = np.clip(4.0 - np.abs(cols - x), 0.0, 1.0) * 200 + 20
    return np.repeat(np.repeat(row[None, :, None], height, 0), 3, 2).astype(np.uint8)


class _Clock:
    """Device clock and transport: true time → (device ns, host ns)."""

    def __init__(
        self, offset_ns: int, drift_ppm: float, latency_s: float, jitter_s: float, seed: int
    ) -> None:
        self.offset_ns, self.drift, self.latency_s, self.jitter_s = (
            offset_ns,
            drift_ppm,
            latency_s,
            jitter_s,
        )
        self.rng = np.random.default_rng(seed)
        self.t0_host_ns = 0

    def stamps(self, t_true_s: float) -> tuple[int, int]:
        t_dev = self.offset_ns + int(round(t_true_s * (1 + self.drift * 1e-6) * 1e9))
        delay = (
            self.latency_s + self.rng.exponential(self.jitter_s)
            if self.jitter_s
            else self.latency_s
        )
        return t_dev, self.t0_host_ns + int(round((t_true_s + delay) * 1e9))


class _Pacer:
    def __init__(self, speed: float | None) -> None:
        self.speed = speed
        self.t0_ns = time.monotonic_ns()

    def wait(self, t_true_s: float, timeout_s: float) -> bool:
        """Sleep until ``t_true_s`` is due; False when that is beyond ``timeout_s``."""
        if self.speed is None:
            return True
        return sleep_until(self.t0_ns + int(t_true_s / self.speed * 1e9), timeout_s)


class _PacedDevice:
    """Open/close of a synthetic device: a real-time pacer and the host clock's zero."""

    speed: float | None
    clock: _Clock
    _pacer: _Pacer | None = None

    def _open(self) -> None:
        self._pacer = _Pacer(self.speed)
        self.clock.t0_host_ns = time.monotonic_ns()

    def _close(self) -> None:
        self._pacer = None


class BarCamera(_PacedDevice, StereoCamera):
    """Stereo camera filming the bar; ``left[0, 0, 0]`` holds ``seq % 256`` for checking."""

    def __init__(
        self,
        width: int = 64,
        height: int = 48,
        fps: float = 30.0,
        speed: float | None = 4.0,
        n_frames: int | None = None,
        disconnect_after: int | None = None,
        drop_seqs: tuple[int, ...] = (),
        offset_ns: int = 5_000_000_000,
        drift_ppm: float = 0.0,
        latency_s: float = 0.0,
        jitter_s: float = 0.0,
        seed: int = 1,
        pixels_per_newton: float = 8.0,
    ) -> None:
        super().__init__()
        self.width, self.height, self.fps = width, height, fps
        self.speed, self.n_frames, self.disconnect_after = speed, n_frames, disconnect_after
        self.drop_seqs = set(drop_seqs)
        self.clock = _Clock(offset_ns, drift_ppm, latency_s, jitter_s, seed)
        self.pixels_per_newton = pixels_per_newton
        self._seq = 0

    def _read_sample(self, timeout_s: float) -> StereoFrame | None:
        if self.disconnect_after is not None and self._seq >= self.disconnect_after:
            raise DeviceError("bar camera unplugged")
        if self.n_frames is not None and self._seq >= self.n_frames:
            time.sleep(timeout_s)
            return None
        t = self._seq / self.fps
        if not self._pacer.wait(t, timeout_s):
            return None
        seq = self._seq
        self._seq += 1
        if seq in self.drop_seqs:  # lost: the base class counts the sequence jump
            return None
        x = self.width / 4 + self.pixels_per_newton * float(force_profile(t)[2])
        left = bar_image(x, self.width, self.height)
        left[0, 0, 0] = seq % 256
        right = bar_image(x - 3, self.width, self.height)
        t_dev, t_host = self.clock.stamps(t)
        return StereoFrame(left, right, seq, t_dev, t_host)


class ProfileForce(_PacedDevice, ForceSensor):
    """Force sensor reading :func:`force_profile` plus noise at ``rate_hz``."""

    def __init__(
        self,
        rate_hz: float = 200.0,
        speed: float | None = 4.0,
        noise_n: float = 0.005,
        offset_ns: int = -3_000_000_000,
        drift_ppm: float = 0.0,
        latency_s: float = 0.0,
        jitter_s: float = 0.0,
        disconnect_after: int | None = None,
        seed: int = 2,
    ) -> None:
        super().__init__()
        self.rate_hz, self.speed, self.noise_n = rate_hz, speed, noise_n
        self.disconnect_after = disconnect_after
        self.clock = _Clock(offset_ns, drift_ppm, latency_s, jitter_s, seed)
        self.rng = np.random.default_rng(seed)
        self._seq = 0

    def _read_sample(self, timeout_s: float) -> ForceSample | None:
        if self.disconnect_after is not None and self._seq >= self.disconnect_after:
            raise DeviceError("profile trocar: CAN interface vcan-test went bus-off")
        t = self._seq / self.rate_hz
        if not self._pacer.wait(t, timeout_s):
            return None
        force = force_profile(t) + self.rng.normal(0, self.noise_n, 3)
        t_dev, t_host = self.clock.stamps(t)
        sample = ForceSample(force, self._seq, t_dev, t_host)
        self._seq += 1
        return sample


class RecordingProjector(Projector):
    """A projector that only reports what it was asked to show."""

    width, height = 64, 48

    def __init__(self) -> None:
        super().__init__()
        self.shown: list[str] = []

    def _open(self) -> None:
        pass

    def _show(self, pattern: np.ndarray, name: str, seq: int) -> int:
        self.shown.append(name)
        return len(self.shown)

    def _close(self) -> None:
        pass


def bar_devices(**camera_options) -> Rig:
    """A camera, trocar and projector sharing the bar scene."""
    force_options = {
        k[6:]: camera_options.pop(k) for k in list(camera_options) if k.startswith("force_")
    }
    force_options.setdefault("speed", camera_options.get("speed", 4.0))
    return Rig(BarCamera(**camera_options), ProfileForce(**force_options), RecordingProjector())


def write_bar_session(path, seconds: float = 7.0, compression: str = "lzf", **options) -> None:
    """Write a session straight through SessionWriter from unpaced bar devices (no threads)."""
    from vbfe.acquire import SessionWriter, finalize_session

    options.setdefault("speed", None)
    devices = bar_devices(**options)
    cam, trocar = devices.camera, devices.trocar
    cam.open()
    trocar.open()
    writer = SessionWriter(
        path, (cam.width, cam.height), compression, {"operator": "synthetic", "devices": {}}
    )
    frames = []
    while len(frames) == 0 or frames[-1].seq / cam.fps < seconds:
        frame = cam.read(0.0)
        if frame is not None:
            frames.append(frame)
    writer.append_frames(frames)
    samples = [trocar.read(0.0) for _ in range(int(seconds * trocar.rate_hz))]
    writer.append_forces(samples)
    writer.close()
    finalize_session(path, {"end_reason": "synthetic"})
