"""Driver-interface devices backed by a :class:`~vbfe.drivers.sim.bench.SimBench`.

They share the bench's simulated time. With ``realtime=False`` the camera is the master: each
read renders the next frame, advances true time by ``1/fps`` and the host clock to the frame's
arrival; the trocar delivers the samples that have arrived by then and waits (up to its
timeout) for the camera otherwise. With
``realtime=True`` samples are delivered when the host clock reaches their arrival time, and a
camera read too late skips (and counts) the frames it missed, like a real capture queue.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.errors import DeviceError
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.samples import ForceSample, ProjectorEvent, StereoFrame
from vbfe.drivers.trocar.base import ForceSensor

if TYPE_CHECKING:
    from vbfe.drivers.sim.bench import SimBench

SAMPLE_BLOCK = 256  # trocar samples generated at once
FORCE_RANGE_N = 5.0  # TRF85D measuring range


def _check_no_options(family: str, options: dict) -> None:
    if options:
        raise DeviceError(f"the simulated {family} takes no options, got {sorted(options)}; "
                          f"remove them from [{family}] or set its backend")


class _BenchStream:
    """Open/close register the device with its bench (the bench's time starts at the first open)."""

    bench: "SimBench"
    _open = False

    def open(self) -> None:
        """Start the stream; idempotent."""
        if not self._open:
            self.bench.device_opened(self)
            self._open = True

    def close(self) -> None:
        """Stop the stream; idempotent."""
        if self._open:
            self.bench.device_closed(self)
            self._open = False


class SimCamera(_BenchStream, StereoCamera):
    """The bench's stereo endoscope: renders the deforming tissue under the current pattern."""

    def __init__(self, bench: "SimBench", **options: object) -> None:
        super().__init__()
        _check_no_options("camera", options)
        self.bench = bench
        self.width, self.height, self.fps = bench.rig.left.width, bench.rig.left.height, bench.fps
        self._next = 0
        self._open = False

    def read(self, timeout_s: float = 1.0) -> StereoFrame | None:
        """Render the next frame; in real time, wait for it (``None`` after ``timeout_s``)."""
        if not self._open:
            raise DeviceError("simulated camera read before open()")
        bench = self.bench
        k = self._next
        if bench.realtime:
            latest = bench.frames_due()
            if latest < k:
                wait_s = (bench.frame_arrival_host_ns(k) - time.monotonic_ns()) / 1e9
                if wait_s > timeout_s:
                    time.sleep(timeout_s)
                    return None
                time.sleep(max(wait_s, 0.0))
            elif latest > k:
                self.stats.dropped += latest - k
                self.stats.gaps.append((k - 1, latest))
                k = latest
        t_true_ns = k * bench.frame_period_ns
        left, right = bench.render_frame(t_true_ns)
        host_ns = int(bench.camera_transport.host_ns(np.array([t_true_ns]))[0])
        self._next = k + 1
        if not bench.realtime:
            bench.advance_to(host_ns)
        self.stats.received += 1
        return StereoFrame(left=left, right=right, seq=k,
                           t_device_ns=int(bench.camera_clock.device_ns(t_true_ns)),
                           t_host_ns=host_ns + bench.host_epoch_ns)

    def describe(self) -> dict[str, object]:
        """Size, rate and the simulated clock's nominal parameters."""
        return {**super().describe(), "simulated": True,
                "drift_ppm": self.bench.camera_clock.drift_ppm}


class SimTrocar(_BenchStream, ForceSensor):
    """The bench's TRF85D: true force + Gaussian noise, quantized, at ``trocar_rate_hz``."""

    def __init__(self, bench: "SimBench", **options: object) -> None:
        super().__init__()
        _check_no_options("trocar", options)
        self.bench = bench
        self.rate_hz = bench.trocar_rate_hz
        self._next = 0
        self._block: dict[str, np.ndarray] = {}
        self._block_start = 0
        self._open = False

    def _sample(self, j: int) -> tuple[int, int, np.ndarray]:
        """Device and host (relative) ns and measured force of sample ``j`` (made in blocks)."""
        offset = j - self._block_start
        if not self._block or offset >= len(self._block["true"]):
            self._block = self.bench.trocar_block(j, SAMPLE_BLOCK)
            self._block_start, offset = j, 0
        b = self._block
        return int(b["device"][offset]), int(b["host"][offset]), b["force"][offset]

    def read(self, timeout_s: float = 1.0) -> ForceSample | None:
        """The next sample once the simulated (or real) host clock has reached its arrival."""
        if not self._open:
            raise DeviceError("simulated trocar read before open()")
        device_ns, host_ns, force = self._sample(self._next)
        if not self.bench.wait_until(host_ns, timeout_s):
            return None
        self.stats.received += 1
        sample = ForceSample(force_n=force - self.offset_n, seq=self._next, t_device_ns=device_ns,
                             t_host_ns=host_ns + self.bench.host_epoch_ns)
        self._next += 1
        return sample

    def describe(self) -> dict[str, object]:
        """Rate, axes, noise model and the simulated clock's nominal parameters."""
        return {**super().describe(), "simulated": True, "axes_frame": "left camera",
                "noise_n": self.bench.force_noise_n, "resolution_n": self.bench.force_resolution_n,
                "range_n": FORCE_RANGE_N, "drift_ppm": self.bench.trocar_clock.drift_ppm}


class SimProjector(Projector):
    """The bench's projector: what it shows is what the simulated cameras see."""

    def __init__(self, bench: "SimBench", **options: object) -> None:
        _check_no_options("projector", options)
        self.bench = bench
        self.width, self.height = bench.rig.projector.width, bench.rig.projector.height
        self._seq = 0
        self._open = False

    def open(self) -> None:
        """Switch the projector on."""
        self._open = True

    def show(self, pattern: np.ndarray, name: str) -> ProjectorEvent:
        """Project ``pattern`` (must be the projector's size) from now on (after the bench's
        projector latency)."""
        if not self._open:
            raise DeviceError("simulated projector used before open()")
        if pattern.shape[:2] != (self.height, self.width):
            raise DeviceError(f"pattern {name!r} is {pattern.shape[1]}x{pattern.shape[0]} but the "
                              f"simulated projector is {self.width}x{self.height}; make it that size")
        event = ProjectorEvent(pattern=name, frame_id=self._seq, seq=self._seq,
                               t_host_ns=self.bench.show_pattern(pattern))
        self._seq += 1
        return event

    def close(self) -> None:
        """Switch the projector off."""
        self._open = False
