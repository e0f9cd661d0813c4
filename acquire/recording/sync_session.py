"""The sync protocol session: projector flashes at random times and operator taps.

While recording, the projector switches between the structured-light pattern and a dimmed copy
of it at random, recorded instants (every switch is a projector event with its host time), and
the operator taps the tissue briefly at irregular intervals; a tap counter watches the force
stream so the progress line can say how many taps are in. :mod:`~vbfe.acquire.sync.protocol`
measures the camera latency from the flashes and the image-force offset from the taps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vbfe.acquire.recording.acquisition import Acquisition, AcquisitionStats
from vbfe.acquire.recording.listener import Listener
from vbfe.common.errors import SessionError
from vbfe.drivers.projector.pattern import PATTERN_NAME
from vbfe.drivers.rig import RigOptions, TapScript
from vbfe.drivers.samples import ForceSample

DIM_NAME = f"{PATTERN_NAME}-dim"  # the flash's other pattern: the same, at DIM_LEVEL brightness
DIM_LEVEL = 0.4
MIN_FLASH_GAP_S = 0.8  # the analysis needs the light steady for this long around each switch
_LEAD_S = 1.0  # no flash in the first second
_LAST_FLASH_S = 0.8  # nor this close to the end (the light must settle before the end)
_TAP_BASELINE_SAMPLES = 300  # force samples that set the tap counter's rest level and noise
_TAP_QUIET_S = 0.25  # a new tap needs the force back at rest this long


def dim(pattern: np.ndarray) -> np.ndarray:
    """The flash's second pattern: ``pattern`` at :data:`DIM_LEVEL` brightness."""
    return np.rint(pattern.astype(np.float32) * DIM_LEVEL).astype(np.uint8)


def flash_schedule(n: int, duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` random flash times (s after the first frame), at least :data:`MIN_FLASH_GAP_S`
    apart, inside ``[1 s, duration_s - 1.5 s]`` (slack for a flash shown late)."""
    span = duration_s - 2.5 * _LEAD_S - (n - 1) * MIN_FLASH_GAP_S
    if n < 1 or span <= 0:
        raise SessionError(
            f"{n} flashes need at least {2.5 * _LEAD_S + (n - 1) * MIN_FLASH_GAP_S:.1f}"
            f" s; record for longer (--duration) or ask for fewer (--flashes)"
        )
    gaps = rng.dirichlet(np.ones(n + 1))[:-1] * span
    return _LEAD_S + np.cumsum(gaps) + np.arange(n) * MIN_FLASH_GAP_S


class TapCounter:
    """Counts taps in the force stream: the force leaving its rest level by more than
    ``max(8 σ, 0.1 N)`` after at least ``_TAP_QUIET_S`` at rest (live, approximate; the
    analysis finds the taps again)."""

    def __init__(self) -> None:
        self.count = 0
        self._warmup: list[np.ndarray] = []
        self._rest: np.ndarray | None = None
        self._threshold = 0.0
        self._quiet_since_ns: int | None = None
        self._in_tap = False

    def feed(self, samples: Sequence[ForceSample]) -> None:
        """Look at a batch of force samples (any thread; one feeder at a time)."""
        for sample in samples:
            force = np.asarray(sample.force_n, np.float64)
            if self._rest is None:
                self._warmup.append(force)
                if len(self._warmup) >= _TAP_BASELINE_SAMPLES:
                    block = np.array(self._warmup)
                    self._rest = np.median(block, axis=0)
                    noise = 1.4826 * np.median(np.abs(np.diff(block, axis=0)), axis=0) / np.sqrt(2)
                    self._threshold = max(8.0 * float(np.linalg.norm(noise)), 0.1)
                continue
            away = float(np.linalg.norm(force - self._rest))
            if away > self._threshold:
                if (
                    not self._in_tap
                    and self._quiet_since_ns is not None
                    and (sample.t_host_ns - self._quiet_since_ns >= _TAP_QUIET_S * 1e9)
                ):
                    self.count += 1
                self._in_tap, self._quiet_since_ns = True, None
            elif away < self._threshold / 2:
                if self._in_tap or self._quiet_since_ns is None:
                    self._quiet_since_ns = sample.t_host_ns
                self._in_tap = False


@dataclass
class SyncProtocol(Listener):
    """What a sync protocol session asks for, and, as a listener of the recording, its live
    state: it counts the taps in the force stream and flashes the projector on schedule."""

    taps: int = 20
    flashes: int = 20
    duration_s: float = 20.0
    seed: int | None = None
    schedule_s: np.ndarray = field(init=False)
    shown: int = field(default=0, init=False)
    tap_counter: TapCounter = field(default_factory=TapCounter, init=False)
    _patterns: tuple[np.ndarray, np.ndarray] | None = field(default=None, init=False)
    _last_flash_ns: int | None = field(default=None, init=False)  # host time of the last flash

    def __post_init__(self) -> None:
        if self.taps < 1:
            raise SessionError(f"the sync protocol needs at least one tap, got {self.taps}")
        self.schedule_s = flash_schedule(
            self.flashes, self.duration_s, np.random.default_rng(self.seed)
        )

    def instructions(self) -> str:
        """What the operator has to do."""
        return (
            f"sync protocol, {self.duration_s:g} s: keep the instrument still on the tissue; "
            f"tap the tissue {self.taps} times, briefly and firmly, at irregular intervals "
            f"(at least 0.5 s apart). The projector will flash {self.flashes} times; keep "
            "the camera's exposure and gain fixed (auto exposure off)."
        )

    def describe(self) -> dict[str, Any]:
        """Session metadata of the protocol."""
        return {
            "kind": "sync",
            "taps_requested": self.taps,
            "flashes_requested": self.flashes,
            "duration_s": self.duration_s,
            "flash_patterns": [PATTERN_NAME, DIM_NAME],
            "dim_level": DIM_LEVEL,
        }

    def rig_options(self) -> RigOptions:
        """How the rig runs the protocol: a simulated operator taps as asked, in real time
        (flashes are timed on the host clock, which a simulation running faster than real
        time outpaces: late flashes would crowd out the last ones)."""
        return RigOptions(realtime=True, taps=TapScript(self.taps, self.duration_s))

    def on_samples(self, samples: Sequence[ForceSample]) -> None:
        """Count the taps."""
        self.tap_counter.feed(samples)

    def on_tick(self, acquisition: Acquisition, stats: AcquisitionStats) -> None:
        """Flash when the session's clock (the newest frame read, against the first frame
        recorded) reaches the next scheduled instant and :data:`MIN_FLASH_GAP_S` has passed
        since the previous flash's host time."""
        if self.shown >= len(self.schedule_s) or stats.frames == 0:
            return
        now_ns = stats.newest_read_host_ns
        now_s = (now_ns - stats.first_frame_host_ns) / 1e9
        if now_s < float(self.schedule_s[self.shown]) or now_s > self.duration_s - _LAST_FLASH_S:
            return
        if self._last_flash_ns is not None and now_ns < self._last_flash_ns + MIN_FLASH_GAP_S * 1e9:
            return
        if self._patterns is None:
            pattern = acquisition.pattern
            assert isinstance(pattern, np.ndarray)  # made from a function by start()
            self._patterns = (pattern, dim(pattern))
        self.shown += 1
        event = acquisition.show(
            self._patterns[self.shown % 2], DIM_NAME if self.shown % 2 else PATTERN_NAME
        )
        self._last_flash_ns = event.t_host_ns

    def progress(self) -> str:
        """The events collected so far, for the progress line."""
        return f"flashes {self.shown}/{self.flashes}, taps {self.tap_counter.count}/{self.taps}"
