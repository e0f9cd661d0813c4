"""Driver-interface devices backed by a :class:`~vbfe.drivers.sim.bench.SimBench`.

They share the bench's simulated time. With ``realtime=False`` the camera is the master: each
read renders the next frame, advances true time by ``1/fps`` and the host clock to the frame's
arrival; the trocar delivers the samples that have arrived by then and waits (up to its
timeout) for the camera otherwise. With
``realtime=True`` samples are delivered when the host clock reaches their arrival time, and a
camera read too late skips (and counts) the frames it missed, like a real capture queue.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from vbfe.common.errors import DeviceError
from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.pacing import sleep_until
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.samples import ForceSample, StereoFrame
from vbfe.drivers.trocar.base import ForceSensor

if TYPE_CHECKING:
    from vbfe.drivers.sim.bench import SimBench

SAMPLE_BLOCK = 256  # trocar samples generated at once


def _check_no_options(family: str, options: dict) -> None:
    if options:
        raise DeviceError(
            f"the simulated {family} takes no options, got {sorted(options)}; "
            f"remove them from [{family}] or set its backend"
        )


class _BenchStream:
    """Open/close register the device with its bench (the bench's time starts at the first open)."""

    bench: SimBench
    drives_time = False  # the camera's frames move the bench's simulated host clock

    def _open(self) -> None:
        """Start the stream."""
        self.bench.device_opened(self, self.drives_time)

    def _close(self) -> None:
        """Stop the stream."""
        self.bench.device_closed(self, self.drives_time)


class SimCamera(_BenchStream, StereoCamera):
    """The bench's stereo endoscope: renders the bench's scene under the current pattern."""

    drives_time = True

    def __init__(self, bench: SimBench, **options: object) -> None:
        super().__init__()
        _check_no_options("camera", options)
        self.bench = bench
        self.width, self.height, self.fps = bench.rig.left.width, bench.rig.left.height, bench.fps
        self._next = 0

    def _read_sample(self, timeout_s: float) -> StereoFrame | None:
        """Render the next frame; in real time, wait for it (``None`` after ``timeout_s``)."""
        bench = self.bench
        k = self._next
        if bench.realtime:
            latest = bench.frames_due()
            if latest < k and not sleep_until(bench.frame_arrival_host_ns(k), timeout_s):
                return None
            elif latest > k:  # missed frames: the base class counts the sequence jump
                k = latest
        t_true_ns = k * bench.frame_period_ns
        left, right = bench.render_frame(t_true_ns)
        host_ns = int(bench.camera_transport.host_ns(np.array([t_true_ns]))[0])
        self._next = k + 1
        if not bench.realtime:
            bench.advance_to(host_ns)
        return StereoFrame(
            left=left,
            right=right,
            seq=k,
            t_device_ns=int(bench.camera_clock.device_ns(t_true_ns)),
            t_host_ns=host_ns + bench.host_epoch_ns,
        )

    def describe(self) -> dict[str, object]:
        """Size, rate, whether frames come in real time (if not, the consumer paces the
        camera) and the simulated clock's nominal parameters."""
        return {
            **super().describe(),
            "simulated": True,
            "realtime": self.bench.realtime,
            "drift_ppm": self.bench.camera_clock.drift_ppm,
        }


class SimTrocar(_BenchStream, ForceSensor):
    """The bench's TRF85D: true force + Gaussian noise, quantized, at ``trocar_rate_hz``."""

    def __init__(self, bench: SimBench, **options: object) -> None:
        super().__init__()
        _check_no_options("trocar", options)
        self.bench = bench
        self.rate_hz = bench.trocar_rate_hz
        self._next = 0
        self._block: dict[str, np.ndarray] = {}
        self._block_start = 0

    def _sample(self, j: int) -> tuple[int, int, np.ndarray]:
        """Device and host (relative) ns and measured force of sample ``j`` (made in blocks)."""
        offset = j - self._block_start
        if not self._block or offset >= len(self._block["true"]):
            self._block = self.bench.trocar_block(j, SAMPLE_BLOCK)
            self._block_start, offset = j, 0
        b = self._block
        return int(b["device"][offset]), int(b["host"][offset]), b["force"][offset]

    def _read_sample(self, timeout_s: float) -> ForceSample | None:
        """The next raw sample once the simulated (or real) host clock has reached its arrival."""
        device_ns, host_ns, force = self._sample(self._next)
        if not self.bench.wait_until(host_ns, timeout_s):
            return None
        sample = ForceSample(
            force_n=force,
            seq=self._next,
            t_device_ns=device_ns,
            t_host_ns=host_ns + self.bench.host_epoch_ns,
        )
        self._next += 1
        return sample

    def describe(self) -> dict[str, object]:
        """Rate, axes, noise model and the simulated clock's nominal parameters."""
        return {
            **super().describe(),
            "simulated": True,
            "axes_frame": "left camera",
            "noise_n": self.bench.force_noise_n,
            "resolution_n": self.bench.force_resolution_n,
            "range_n": self.bench.force_range_n,
            "drift_ppm": self.bench.trocar_clock.drift_ppm,
        }


class SimProjector(Projector):
    """The bench's projector: what it shows is what the simulated cameras see."""

    def __init__(self, bench: SimBench, **options: object) -> None:
        super().__init__(lambda: self._shown_at_ns)  # events carry the bench's command time
        _check_no_options("projector", options)
        self._shown_at_ns = 0
        self.bench = bench
        self.width, self.height = bench.rig.projector.width, bench.rig.projector.height

    def _open(self) -> None:
        """Switch the projector on."""

    def _show(self, pattern: np.ndarray, name: str, seq: int) -> int:
        """Project ``pattern`` (must be the projector's size) from now on (after the bench's
        projector latency); frame ID = ``seq``."""
        if pattern.shape[:2] != (self.height, self.width):
            raise DeviceError(
                f"pattern {name!r} is {pattern.shape[1]}x{pattern.shape[0]} but the "
                f"simulated projector is {self.width}x{self.height}; make it that size"
            )
        self._shown_at_ns = self.bench.show_pattern(pattern)
        return seq

    def _close(self) -> None:
        """Switch the projector off."""
