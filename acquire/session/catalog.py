"""The sessions in a data folder, one line each: when, how long, how much, what was lost,
whether its sync was verified, how many markers (the console's Review browser)."""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from pathlib import Path

from vbfe.acquire.session.audit import audit_sequence
from vbfe.acquire.session.layout import CAMERA, FORCE
from vbfe.acquire.session.reader import SessionReader
from vbfe.common.errors import VbfeError

MAX_DEPTH = 3  # folders below the data folder searched (a file template may make some)


@dataclass(frozen=True)
class SessionEntry:
    """One session file as the browser lists it (``problem``: why it could not be read)."""

    path: Path
    started_utc: datetime.datetime | None = None
    duration_s: float = 0.0
    frames: int = 0
    dropped: int = 0  # camera frames and force samples lost
    sync: str = "-"  # verify-sync's verdict, "-" when not verified
    markers: int = 0
    participant: str = ""
    task: str = ""
    status: str = ""  # complete, or how it ended
    problem: str = ""

    def row(self) -> tuple[str, ...]:
        """The browser's columns (:data:`COLUMNS`)."""
        if self.problem:
            return (self.path.name, "-", "-", "-", "-", "-", "-", "-", self.problem)
        started = f"{self.started_utc:%Y-%m-%d %H:%M:%S}" if self.started_utc else "-"
        subject = " / ".join(x for x in (self.participant, self.task) if x) or "-"
        return (
            self.path.name,
            started,
            f"{self.duration_s:.1f} s",
            str(self.frames),
            str(self.dropped),
            self.sync,
            str(self.markers),
            subject,
            self.status,
        )


COLUMNS = (
    "session",
    "started (UTC)",
    "duration",
    "frames",
    "dropped",
    "sync",
    "markers",
    "participant / task",
    "status",
)


def session_entry(path: Path) -> SessionEntry:
    """Read one session's line (a file that is not a readable session: its problem)."""
    try:
        with SessionReader(path) as r:
            frame_t = r.frame_times_ns()
            start = r.attrs.get("start_utc_ns")
            meta = r.metadata
            dropped = sum(audit_sequence(r.stream_times(s)[2]).dropped for s in (CAMERA, FORCE))
            end = r.attrs.get("end_reason") or "closed"
            return SessionEntry(
                path,
                datetime.datetime.fromtimestamp(int(start) / 1e9, datetime.timezone.utc)
                if start
                else None,
                (frame_t[-1] - frame_t[0]) / 1e9 if len(frame_t) > 1 else 0.0,
                r.n_frames,
                dropped,
                str(r.analysis().get("sync_verdict", "-")).upper(),
                len(r.events()),
                str(meta.get("participant") or ""),
                str(meta.get("task") or ""),
                f"complete ({end})" if r.complete else "NOT CLOSED CLEANLY",
            )
    except (VbfeError, OSError) as exc:
        return SessionEntry(path, problem=" ".join(str(exc).split()))


def list_sessions(folder: str | Path) -> list[SessionEntry]:
    """The ``.h5`` sessions in ``folder`` (and up to :data:`MAX_DEPTH` folders below), newest
    first."""
    folder = Path(folder)
    paths = [p for depth in range(MAX_DEPTH + 1) for p in folder.glob("*/" * depth + "*.h5")]
    entries = [session_entry(p) for p in sorted(paths)]
    return sorted(
        entries,
        key=lambda e: e.started_utc or datetime.datetime.min.replace(tzinfo=datetime.timezone.utc),
        reverse=True,
    )
