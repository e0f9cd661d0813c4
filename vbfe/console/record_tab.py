"""Record tab: the session's file name (a LabRecorder template with a running number; an
existing file is refused, never overwritten), operator, notes, conditions; the streams a
recording holds (from the rig configuration) with their records while it runs; Start/Stop, a
marker button (and the M key); elapsed time, MB/s, free disk, drops; remote control while it
runs."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import TYPE_CHECKING

from pyqtgraph.Qt import QtWidgets

from vbfe.acquire.recording.remote import (
    RemoteControl,
    RemoteSessions,
    first_free_run,
    session_path,
)
from vbfe.acquire.recording.storage import free_bytes
from vbfe.acquire.session.estimates import GROUP as ESTIMATE
from vbfe.acquire.session.extra_streams import MARKS
from vbfe.common.errors import SessionError, VbfeError
from vbfe.common.files import error_line, stale_locks
from vbfe.common.settings import parse_conditions
from vbfe.console.station import Finished, SessionRequest
from vbfe.console.widgets import Tab, form, readonly_table, show_rows, value_label, with_picker

if TYPE_CHECKING:
    from vbfe.console.window import ConsoleWindow

DEFAULT_TEMPLATE = "%p_%b_run-%n.h5"
STREAM_COLUMNS = ("stream", "records", "from")


def make_session_folder(root: Path, path: Path) -> Path | None:
    """Make the folders ``path`` needs under the data folder ``root``: ``root`` itself only
    when its parent exists (a mistyped folder is not made several levels deep), the template's
    subfolders under it. Returns the first folder made, if any."""
    if path.parent.is_dir():
        return None
    if not root.is_dir() and not root.parent.is_dir():
        raise SessionError(
            f"the data folder {root} does not exist, nor does {root.parent}: choose an "
            "existing folder in 'folder'"
        )
    made = next(p for p in [*reversed(path.parents), path.parent] if not p.is_dir())
    path.parent.mkdir(parents=True, exist_ok=True)
    return made


class RemoteRecording:
    """A recording remote control started in the console (``vbfe record --remote``'s
    :class:`~vbfe.acquire.recording.remote.Recording`): the station records it."""

    def __init__(self, tab: RecordTab, path: Path) -> None:
        self.station = tab.station
        request = dataclasses.replace(tab.remote_request, path=path, duration_s=None)
        self.station.submit(self.station.start_recording, request).result()

    def mark(self, text: str, t_host_ns: int) -> None:
        """An event mark (at the host's now)."""
        self.station.mark(text)

    def stop(self, reason: str = "stopped by remote control") -> str:
        """Stop and finalize; the one-line summary."""
        return self.station.submit(self.station.stop_recording, reason).result().line()


class RecordTab(Tab):
    """The session form, the controls and the running recording's numbers."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__(console)
        layout = QtWidgets.QVBoxLayout(self)
        self.root = QtWidgets.QLineEdit(str(console.options.out_dir))
        self.template = QtWidgets.QLineEdit(DEFAULT_TEMPLATE)
        self.participant = QtWidgets.QLineEdit("P001")
        self.task = QtWidgets.QLineEdit("traction")
        self.operator = QtWidgets.QLineEdit()
        self.notes = QtWidgets.QLineEdit()
        self.conditions = QtWidgets.QLineEdit()
        self.conditions.setPlaceholderText("KEY=VALUE, KEY=VALUE")
        self.duration = QtWidgets.QDoubleSpinBox()
        self.duration.setRange(0.0, 24 * 3600.0)
        self.duration.setSuffix(" s (0: until Stop)")
        self.next_file = value_label()
        layout.addLayout(
            form(
                [
                    ("folder", with_picker(self.root, "folder", "data folder")),
                    ("file template (%p %b %n)", self.template),
                    ("participant (%p)", self.participant),
                    ("task (%b)", self.task),
                    ("operator", self.operator),
                    ("notes", self.notes),
                    ("conditions", self.conditions),
                    ("duration", self.duration),
                    ("next file", self.next_file),
                ]
            )
        )
        self.streams = readonly_table(STREAM_COLUMNS)
        layout.addWidget(QtWidgets.QLabel("streams recorded (from the rig configuration)"))
        layout.addWidget(self.streams, 1)
        buttons = QtWidgets.QHBoxLayout()
        self.start_button = QtWidgets.QPushButton("Start")
        self.stop_button = QtWidgets.QPushButton("Stop")
        self.mark_button = QtWidgets.QPushButton("Marker (M)")
        self.start_button.clicked.connect(self.start)
        self.stop_button.clicked.connect(self.stop)
        self.mark_button.clicked.connect(self.add_marker)
        for button in (self.start_button, self.stop_button, self.mark_button):
            buttons.addWidget(button)
        layout.addLayout(buttons)
        self.numbers = value_label()
        layout.addWidget(self.numbers)
        self.warning = value_label()  # drops while recording
        self.warning.setStyleSheet("color: #ffffff; background: #c00000; padding: 4px")
        self.warning.hide()
        layout.addWidget(self.warning)
        self.remote_label = value_label()
        layout.addWidget(self.remote_label)
        self.last = value_label()
        layout.addWidget(self.last)
        self.stale = value_label()  # sessions a killed recorder left unfinished
        self.stale.setStyleSheet("color: #c00000")
        layout.addWidget(self.stale)
        self.root.editingFinished.connect(self.check_stale)
        self.remote: RemoteControl | None = None
        self.remote_sessions: RemoteSessions | None = None
        # the form as remote control's recordings take it (read by its threads, which must
        # not touch widgets; kept up to date by refresh)
        self.remote_request = SessionRequest(Path())
        self.stopping = False  # Stop pressed, the session being finalized
        self.check_stale()

    # -- the form -----------------------------------------------------------------------------
    def options(self) -> dict[str, str]:
        """The form as remote control's ``filename`` options (an empty folder or template is
        refused, naming the field)."""
        root, template = self.root.text().strip(), self.template.text().strip()
        if not root:
            raise SessionError("no data folder: fill in 'folder'")
        if not template:
            raise SessionError(
                f"no file template: fill in 'file template', e.g. {DEFAULT_TEMPLATE}"
            )
        return {
            "root": root,
            "template": template,
            "participant": self.participant.text().strip(),
            "task": self.task.text().strip(),
        }

    def next_path(self) -> Path:
        """The next session file: the first run number whose file does not exist."""
        return session_path(first_free_run(self.options()))

    def request(self, path: Path) -> SessionRequest:
        """A recording of ``path`` with the form's operator, notes, conditions, duration."""
        pairs = [p.strip() for p in self.conditions.text().split(",") if p.strip()]
        duration = self.duration.value()
        return SessionRequest(
            path,
            self.operator.text(),
            self.notes.text(),
            parse_conditions(pairs),
            duration if duration > 0 else None,
            self.participant.text().strip(),
            self.task.text().strip(),
        )

    def check_stale(self) -> None:
        """Explain the sessions in the data folder whose recorder died while writing them."""
        root = Path(self.root.text().strip() or ".")
        stale = stale_locks(root) if root.is_dir() else []
        self.stale.setText(
            "".join(
                f"{path.name} was not closed cleanly: its recorder (process {pid}) was killed "
                "or lost power while recording; it is readable up to its last flush (Review "
                f"tab), and the lock file .{path.name}.lock it left may be deleted\n"
                for path, pid in stale
            ).strip()
        )

    # -- controls -----------------------------------------------------------------------------
    def start(self) -> None:
        """Record into the next file."""
        try:
            path = self.next_path()
            request = self.request(path)
            made = make_session_folder(Path(self.options()["root"]), path)
        except (VbfeError, OSError) as exc:
            self.console.message(f"cannot record: {error_line(exc)}", True)
            return
        said = f" (made the folder {made})" if made is not None else ""
        self.console.rig_op(
            self.station.start_recording,
            request,
            on_done=lambda p: self.console.message(f"recording {p}{said}"),
            what="cannot record",
        )

    def stop(self) -> None:
        """Stop and finalize the recording."""
        if self.station.recording is None:
            self.console.message("nothing is being recorded", True)
            return
        self.stopping = True
        self.console.rig_op(self.station.stop_recording, what="stop", on_error=self._stopped)

    def _stopped(self, _: object = None) -> None:
        self.stopping = False

    def add_marker(self) -> None:
        """A marker at the host's now ("marker <n>")."""
        try:
            self.station.mark(f"marker {self.station.marks + 1}")
        except VbfeError as exc:
            self.console.message(str(exc), True)
            return
        self.console.message(f"marker {self.station.marks} added")

    # -- remote control -----------------------------------------------------------------------
    def listen(self, port: int, bind: str = "127.0.0.1") -> int:
        """Serve ``vbfe record --remote``'s commands on ``port`` (0: any free one); returns it."""
        self.remote_sessions = RemoteSessions(
            lambda path: RemoteRecording(self, path), on_message=lambda m: None
        )
        self.remote = RemoteControl(self.remote_sessions, port, bind)
        self.remote_label.setText(f"remote control: listening on {bind}:{self.remote.port}")
        return self.remote.port

    def close_remote(self) -> None:
        """Stop listening (the window finalizes a running recording itself)."""
        if self.remote is not None:
            self.remote.close()
            self.remote = None

    # -- view ---------------------------------------------------------------------------------
    def refresh(self) -> None:
        try:
            self.remote_request = self.request(Path())
        except VbfeError:  # conditions being typed: the last good form stays
            pass
        recording = self.station.recording
        self.start_button.setEnabled(recording is None and not self.stopping)
        self.stop_button.setEnabled(recording is not None and not self.stopping)
        self.mark_button.setEnabled(recording is not None and not self.stopping)
        if not self.isVisible() and recording is None:
            return
        try:
            self.next_file.setText(str(self.next_path()))
        except VbfeError as exc:
            self.next_file.setText(str(exc))
        self.show_streams(recording is not None)
        stats = self.station.stats()
        if self.stopping:
            self.numbers.setText(f"stopping: finalizing {recording or 'the session'}…")
            return
        if recording is None or stats is None:
            self.numbers.setText("not recording")
            return
        dropped = {k: n for k, n in stats.dropped.items() if n > 0}
        self.warning.setVisible(bool(dropped))
        if dropped:
            self.warning.setText(
                "⚠ data lost while recording: "
                + ", ".join(f"{k} dropped {n}" for k, n in dropped.items())
                + " (a busy machine or a device that cannot keep up; see the Rig tab)"
            )
        folder = recording.parent
        free = free_bytes(folder) / 1e9 if os.path.isdir(folder) else float("nan")
        self.numbers.setText(
            f"recording {recording}\nelapsed {stats.elapsed_s:.1f} s | {stats.frames} frames, "
            f"{stats.samples} force samples | {stats.write_rate_mb_s:.1f} MB/s | free disk "
            f"{free:.1f} GB | dropped {sum(stats.dropped.values())} | "
            f"markers {self.station.marks}"
        )

    def show_streams(self, recording: bool) -> None:
        """The streams a recording holds; their records so far while one runs."""
        station = self.station
        status = station.live_status()
        counts = {MARKS: station.marks, ESTIMATE: status.estimates if status else 0}
        rows = [
            (
                p.name,
                str(counts.get(p.name, station.latest.view(p.name).count)) if recording else "-",
                p.source,
            )
            for p in station.planned_streams()
        ]
        show_rows(self.streams, rows)

    def on_finished(self, finished: Finished) -> None:
        self.stopping = False
        self.last.setText(f"last session: {finished.line()}")
        self.check_stale()
