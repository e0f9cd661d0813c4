"""Real LSL outlets standing in for a lab's other programs: a robot publishing its joint state
at 1 kHz (as docs/how-to/publish-streams.md's ROS 2 bridge does) and an experiment script's
marker stream."""

from __future__ import annotations

import time
import uuid

import numpy as np
import pylsl

from tests.fakes.threaded import ThreadedFake


def unique(prefix: str) -> str:
    """A stream name no other test (or engineer on this machine) publishes."""
    return f"{prefix}-{uuid.uuid4().hex[:8]}"


class FakeRobot(ThreadedFake):
    """Publishes ``joints`` joint positions (rad) at ``rate_hz``, stamped on the host clock.

    Samples are due on an exact ``rate_hz`` grid from the start and pushed in small batches as
    their time comes (each stamped with its due time); ``pushed`` counts them. :meth:`pause`
    makes it skip the samples due for a while (a publisher that stalled: they are never sent).
    Joint 0 is still until ``onset_ns`` (host clock), then moves at 0.5 rad/s."""

    def __init__(
        self, name: str, rate_hz: float = 1000.0, joints: int = 7, onset_ns: int | None = None
    ) -> None:
        super().__init__(f"fake-robot-{name}")
        self.name, self.rate_hz, self.joints, self.onset_ns = name, rate_hz, joints, onset_ns
        info = pylsl.StreamInfo(
            name, "RobotState", joints, rate_hz, pylsl.cf_double64, f"{name}-serial-1"
        )
        channels = info.desc().append_child("channels")
        for j in range(joints):
            channel = channels.append_child("channel")
            channel.append_child_value("label", f"joint{j + 1}_position")
            channel.append_child_value("unit", "rad")
        self.outlet = pylsl.StreamOutlet(info, chunk_size=1)
        self.pushed = 0
        self.first_ns: int | None = None
        self._next = 0  # grid index of the next sample due
        self._sent: list[np.ndarray] = []  # grid indices pushed
        self._pause_ns: tuple[int, int] | None = None

    def pause(self, duration_s: float) -> None:
        """Send nothing for ``duration_s`` from now; the samples due meanwhile are skipped."""
        now = time.monotonic_ns()
        self._pause_ns = (now, now + int(duration_s * 1e9))
        time.sleep(duration_s)

    def value(self, t_ns: np.ndarray) -> np.ndarray:
        """The joint positions due at host times ``t_ns`` (n × joints)."""
        t_s = (t_ns - self.first_ns) / 1e9
        out = 0.1 * np.sin(2 * np.pi * 0.5 * t_s[:, None] + np.arange(self.joints))
        moving = 0.0 if self.onset_ns is None else np.clip((t_ns - self.onset_ns) / 1e9, 0, None)
        out[:, 0] = 0.5 * moving
        return out

    def _run(self) -> None:
        period_ns = int(round(1e9 / self.rate_hz))
        self.first_ns = time.monotonic_ns()
        while not self._stop.is_set():
            time.sleep(0.004)
            index = np.arange(self._next, (time.monotonic_ns() - self.first_ns) // period_ns + 1)
            due = self.first_ns + period_ns * index
            if self._pause_ns is not None:
                start, end = self._pause_ns
                if time.monotonic_ns() < end:
                    continue
                keep = (due < start) | (due >= end)
                index, due = index[keep], due[keep]
            if len(index):
                self.outlet.push_chunk(self.value(due), (due / 1e9).tolist())
                self._sent.append(index)
                self.pushed += len(index)
                self._next = int(index[-1]) + 1

    def due_times_ns(self) -> np.ndarray:
        """Host times of every sample pushed so far."""
        index = np.concatenate(self._sent) if self._sent else np.zeros(0, np.int64)
        return self.first_ns + int(round(1e9 / self.rate_hz)) * index


class MarkerOutlet:
    """An experiment script's marker stream (strings, irregular rate)."""

    def __init__(self, name: str) -> None:
        self.name = name
        info = pylsl.StreamInfo(
            name, "Markers", 1, pylsl.IRREGULAR_RATE, pylsl.cf_string, f"{name}-script"
        )
        self.outlet = pylsl.StreamOutlet(info)
        self.sent: list[tuple[int, str]] = []

    def mark(self, text: str) -> int:
        """Push ``text`` stamped now; returns the host time."""
        now = time.monotonic_ns()
        self.outlet.push_sample([text], now / 1e9)
        self.sent.append((now, text))
        return now
