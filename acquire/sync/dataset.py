"""The dataset view of sync: each session's stored offset in recording order, and the steps.

A driver update or a USB hub added mid-study changes the image latency from one session to the
next. Each session's ``verify-sync`` result (offset and 95% interval, in its ``/analysis``) is
read back, the sessions are put in recording order (their start time), and a step is flagged
between two consecutive sessions whose offsets differ by more than the limit and by more than
``STEP_SIGMAS`` standard errors of the difference (each session's standard error from its 95%
interval).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vbfe.acquire.session.reader import SessionReader
from vbfe.common.errors import SessionError
from vbfe.common.files import save_figure

STEP_SIGMAS = 4.0


@dataclass(frozen=True)
class SessionOffset:
    """One session's stored sync result."""

    path: Path
    start_ns: int  # first frame on the host clock: the recording order
    offset_s: float
    ci95_s: tuple[float, float]
    verdict: str

    @property
    def std_s(self) -> float:
        """Standard error from the 95% interval."""
        return (self.ci95_s[1] - self.ci95_s[0]) / (2 * 1.96)


@dataclass(frozen=True)
class Step:
    """A change of the offset between two consecutive sessions."""

    before: SessionOffset
    after: SessionOffset

    @property
    def change_s(self) -> float:
        """Later minus earlier offset."""
        return self.after.offset_s - self.before.offset_s

    def text(self) -> str:
        """One line naming the sessions and the change."""
        return (
            f"step {1e3 * self.change_s:+.2f} ms between {self.before.path.name} and "
            f"{self.after.path.name}: the image-force latency changed between them"
        )


def stored_offset(path: str | Path) -> SessionOffset:
    """The offset ``verify-sync`` stored in a session; SessionError when it holds none."""
    with SessionReader(path) as reader:
        analysis = reader.analysis()
        if "sync_offset_s" not in analysis:
            raise SessionError(f"{path} holds no sync result; run vbfe verify-sync on it first")
        start = int(reader.frame_times_ns()[0]) if reader.n_frames else 0
        start = int(reader.attrs.get("start_utc_ns") or start)
    return SessionOffset(
        Path(path),
        start,
        float(analysis["sync_offset_s"]),
        (float(analysis["sync_offset_ci95_low_s"]), float(analysis["sync_offset_ci95_high_s"])),
        str(analysis.get("sync_verdict", "")).upper(),
    )


def in_recording_order(sessions: Sequence[str | Path]) -> list[SessionOffset]:
    """The sessions' stored offsets, earliest recording first."""
    return sorted((stored_offset(p) for p in sessions), key=lambda s: s.start_ns)


def find_steps(offsets: list[SessionOffset], limit_s: float) -> list[Step]:
    """Consecutive sessions whose offsets differ by more than ``limit_s`` and by more than
    ``STEP_SIGMAS`` standard errors of the difference."""
    steps = []
    for before, after in zip(offsets[:-1], offsets[1:], strict=True):
        change = abs(after.offset_s - before.offset_s)
        if change > limit_s and change > STEP_SIGMAS * np.hypot(before.std_s, after.std_s):
            steps.append(Step(before, after))
    return steps


def plot_offsets(path: str | Path, offsets: list[SessionOffset], steps: list[Step]) -> None:
    """Offset per session in recording order with its 95% interval; steps marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.arange(len(offsets))
    value = np.array([1e3 * s.offset_s for s in offsets])
    low = value - np.array([1e3 * s.ci95_s[0] for s in offsets])
    high = np.array([1e3 * s.ci95_s[1] for s in offsets]) - value
    fig, ax = plt.subplots(figsize=(max(6.0, 0.35 * len(offsets)), 3.5))
    ax.errorbar(x, value, yerr=[low, high], fmt="o", capsize=3, label="offset (95% CI)")
    index = {id(s): i for i, s in enumerate(offsets)}
    for n, step in enumerate(steps):
        ax.axvline(
            index[id(step.after)] - 0.5,
            color="tab:red",
            linestyle="--",
            label="step" if n == 0 else None,
        )
    ax.set_xticks(x, [s.path.stem for s in offsets], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("image time - force time (ms)")
    ax.set_title("sync offset per session, in recording order")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=100)
    finally:
        plt.close(fig)
