"""The console window: the tabs over one :class:`~vbfe.console.station.Station`, a timer that
polls it, and the one place where work handed to threads comes back (results to the tab that
asked, failures as a one-line message in the window)."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pyqtgraph.Qt import QtCore, QtGui, QtWidgets

from vbfe.calib import BoardSpec
from vbfe.common.errors import VbfeError
from vbfe.common.files import error_line
from vbfe.console import TAB_NAMES
from vbfe.console.station import Finished, Station
from vbfe.drivers.qt_app import qt_application

# The CLI's options that refusals name, as the window's fields (the rest of the words stay)
WINDOW_TERMS = {
    "pass --overwrite to replace it or choose a new name": "choose a new name in the window",
    "--swap-eyes": "'swap eyes' (Calibrate tab)",
    "--intrinsics LEFT RIGHT": "the 'fixed intrinsics' files (Calibrate tab)",
    "--intrinsics": "the 'fixed intrinsics' files (Calibrate tab)",
    "--min-views": "'fewest views' (Calibrate tab)",
    "--target": "'board' (Calibrate tab)",
    "--inner-corners": "'squares' (Calibrate tab)",
    "--squares-x, --squares-y": "'squares' (Calibrate tab)",
    "--square-mm": "'square size' (Calibrate tab)",
    "--marker-mm": "'marker size' (Calibrate tab)",
    "--condition": "'conditions' (Record tab)",
    "--config": "the rig file (Rig tab)",
    "--calib": "the calibration (Live tab)",
    "--model": "the model (Live tab)",
}
_TERMS = re.compile("|".join(re.escape(k) for k in sorted(WINDOW_TERMS, key=len, reverse=True)))


def window_terms(text: str) -> str:
    """``text`` with the CLI's options it names replaced by the window's fields."""
    return _TERMS.sub(lambda m: WINDOW_TERMS[m.group(0)], text)


@dataclass(frozen=True)
class _Pending:
    """Work handed to a thread: what to call with its result, or on its failure."""

    future: Future
    on_done: Callable[[Any], None] | None
    what: str
    on_error: Callable[[], None] | None = None


@dataclass(frozen=True)
class ConsoleOptions:
    """Where the console writes and what it was given.

    :param out_dir: default folder of sessions, views, calibrations and reports.
    :param stored_calibration: the calibration the GO/NO-GO check compares against.
    :param overwrite: replace existing calibration files (sessions are never replaced).
    :param live_when_idle: show the rig live when nothing is recorded (off in headless runs).
    :param rig_file: where what the operator settles (board, calibration, sync correction,
        model) is written back; ``None``: nowhere (the window says so).
    """

    out_dir: Path
    stored_calibration: Path | None = None
    overwrite: bool = False
    live_when_idle: bool = True
    rig_file: Path | None = None


class ConsoleWindow(QtWidgets.QMainWindow):
    """Rig, Live, Record, Calibrate, Sync and Review tabs over ``station``; M marks the
    recording. Closing the window finalizes a running recording."""

    def __init__(self, station: Station, options: ConsoleOptions, interval_ms: int = 50) -> None:
        from vbfe.console.calibrate_tab import CalibrateTab
        from vbfe.console.live_tab import LiveTab
        from vbfe.console.record_tab import RecordTab
        from vbfe.console.review_tab import ReviewTab
        from vbfe.console.rig_tab import RigTab
        from vbfe.console.sync_tab import SyncTab

        qt_application()
        super().__init__()
        self.station, self.options = station, options
        self.setWindowTitle("vbfe console")
        self.resize(1100, 720)
        self.work = ThreadPoolExecutor(1, thread_name_prefix="vbfe-console-work")
        self._pending: list[_Pending] = []
        self._settling = False
        self.finished_hooks: list[Callable[[Finished], None]] = []
        self.message_label = QtWidgets.QLabel()
        self.message_label.setWordWrap(True)
        self.errors: list[str] = []
        self.confirm_close = True  # ask before a close ends a recording (off in headless runs)
        self.tabs = QtWidgets.QTabWidget()
        self.rig_tab = RigTab(self)
        self.live_tab = LiveTab(self)
        self.record_tab = RecordTab(self)
        self.calibrate_tab = CalibrateTab(self)
        self.sync_tab = SyncTab(self)
        self.review_tab = ReviewTab(self)
        for name, tab in self.named_tabs().items():
            self.tabs.addTab(tab, name)
        self.setCentralWidget(self.tabs)
        self.statusBar().addWidget(self.message_label, 1)
        self.timer = QtCore.QTimer(self)
        self.timer.timeout.connect(self.refresh)
        self.timer.start(interval_ms)
        self.load_settled()

    def named_tabs(self) -> dict[str, QtWidgets.QWidget]:
        """The tabs by name, in order."""
        tabs = (
            self.rig_tab,
            self.live_tab,
            self.record_tab,
            self.calibrate_tab,
            self.sync_tab,
            self.review_tab,
        )
        return dict(zip(TAB_NAMES, tabs, strict=True))

    # -- work handed to threads ---------------------------------------------------------------
    def rig_op(
        self,
        fn: Callable[..., Any],
        *args: Any,
        on_done: Callable[[Any], None] | None = None,
        what: str = "",
        on_error: Callable[[], None] | None = None,
    ) -> None:
        """Run ``fn(*args)`` on the station's rig thread; ``on_done(result)`` back here (a
        failure: its message, then ``on_error()``)."""
        self._pending.append(_Pending(self.station.submit(fn, *args), on_done, what, on_error))

    def work_op(
        self,
        fn: Callable[..., Any],
        *args: Any,
        on_done: Callable[[Any], None] | None = None,
        what: str = "",
        on_error: Callable[[], None] | None = None,
    ) -> None:
        """Run long work (calibration, analysis, reports) off the UI thread (as :meth:`rig_op`)."""
        self._pending.append(_Pending(self.work.submit(fn, *args), on_done, what, on_error))

    def busy(self) -> bool:
        """Whether work handed to a thread has not come back yet."""
        return bool(self._pending) or self._settling

    def message(self, text: str, error: bool = False) -> None:
        """Show ``text`` in the status bar (red for an error, the CLI's options it names
        replaced by the window's fields)."""
        if error:
            text = window_terms(text)
        self.message_label.setStyleSheet("color: #c00000" if error else "")
        self.message_label.setText(text)
        if error:
            self.errors.append(text)

    def use_rig_file(self, path: Path) -> None:
        """Run the rig configuration of ``path`` from the next acquisition on (new sessions
        name it as their rig file), show its board, load the calibration and model it settled,
        and keep what the operator settles there.

        :raises ConfigError: the file is missing or has a bad key (nothing changed).
        """
        from vbfe.rig_config import load_rig

        config = load_rig(path, named_by="the Rig tab")
        self.station.config = config
        self.options = dataclasses.replace(self.options, rig_file=path)
        self.calibrate_tab.board.show_config()
        self.load_settled()

    def load_settled(self) -> None:
        """Load the calibration and model the rig file names (settled on an earlier day)."""
        live = self.live_tab
        calibration = self.station.config.calib.calibration
        model = self.station.config.live.model
        if calibration and self.station.calibration is None:
            live.calibration.setText(calibration)
            live.load_calibration()
            if model and self.station.estimator is None:
                live.model.setText(model)
                live.load_model()

    def close_now(self) -> None:
        """Close without asking (Ctrl-C, SIGTERM): a running recording is finalized."""
        self.confirm_close = False
        self.close()

    def ask(self, question: str) -> bool:
        """A yes/no question to the operator (no: the default)."""
        buttons = QtWidgets.QMessageBox.StandardButton
        answer = QtWidgets.QMessageBox.question(
            self, "vbfe console", question, buttons.Yes | buttons.No, buttons.No
        )
        return answer == buttons.Yes

    def settled(
        self,
        board: BoardSpec | None = None,
        calibration: Path | None = None,
        correction_s: float | None = None,
        model: Path | None = None,
    ) -> None:
        """Use what the operator settled from now on, and write it into the rig file (comments
        kept, the previous file backed up), so that the next window starts there; without a
        rig file, say so."""
        changes: dict[str, dict[str, Any]] = {}
        if board is not None:
            changes["calib"] = board.calib_table()
        if calibration is not None:
            changes.setdefault("calib", {})["calibration"] = str(calibration.absolute())
        if correction_s is not None:
            changes["record"] = {"frame_time_correction_s": correction_s}
        if model is not None:
            changes["live"] = {"model": str(model.absolute())}
        if not changes:
            return
        try:
            self.station.reconfigure(changes)
        except VbfeError as exc:
            self.message(f"not used: {error_line(exc)}", True)
            return
        rig_file = self.options.rig_file
        if rig_file is None:
            self.message(
                self.message_label.text()
                + " (not kept for the next day: no rig file; save one on the Rig tab)"
            )
            return
        from vbfe.common.rig_writeback import write_back
        from vbfe.rig_config import check_file

        try:  # checked as a whole rig file before it is written, as `--settle` does
            done = write_back(rig_file, changes, check=check_file)
        except (VbfeError, OSError) as exc:
            self.message(f"rig file not updated: {error_line(exc)}", True)
            return
        if done.changes:
            self.message(
                self.message_label.text()
                + f"; kept in {rig_file}"
                + (f" (previous file: {done.backup.name})" if done.backup else "")
            )

    # -- polling ------------------------------------------------------------------------------
    def refresh(self) -> None:
        """Hand back finished work, finish an acquisition that ended, redraw the tabs."""
        done = [p for p in self._pending if p.future.done()]
        self._pending = [p for p in self._pending if not p.future.done()]
        for p in done:
            exc = p.future.exception()
            if exc is not None:
                self.message(f"{p.what}: {error_line(exc)}" if p.what else error_line(exc), True)
                if p.on_error is not None:
                    p.on_error()
            elif p.on_done is not None:
                p.on_done(p.future.result())
        while not self.station.finished.empty():
            self.recording_finished(self.station.finished.get())
        if self.station.ended() and not self._settling:
            self._settling = True
            self.rig_op(self.station.settle, on_done=self._settled, on_error=self._unsettled)
        for tab in self.named_tabs().values():
            tab.refresh()

    def _unsettled(self) -> None:
        self._settling = False

    def _settled(self, result: Finished | str | None) -> None:
        self._settling = False
        if isinstance(result, str):  # a recording's summary comes in station.finished
            self.message(f"the rig stopped: {result}; reopen it on the Rig tab", True)

    def recording_finished(self, finished: Finished) -> None:
        """A recording ended (stopped, its duration, a full disk): tell the tabs, go live."""
        self.message(finished.line())
        for tab in self.named_tabs().values():
            tab.on_finished(finished)
        for hook in self.finished_hooks:
            hook(finished)
        if self.options.live_when_idle:
            self.rig_op(self.station.go_live, what="live view")

    # -- Qt events ----------------------------------------------------------------------------
    def keyPressEvent(self, event: QtGui.QKeyEvent) -> None:  # noqa: N802 - Qt's name
        """M puts a marker into the recording (text fields keep their letters)."""
        if event.key() == QtCore.Qt.Key.Key_M:
            self.record_tab.add_marker()
            return
        super().keyPressEvent(event)

    def closeEvent(self, event: QtGui.QCloseEvent) -> None:  # noqa: N802 - Qt's name
        """Finalize a running recording (after asking) and close the rig before the window
        goes."""
        recording = self.station.recording
        if (
            recording is not None
            and self.confirm_close
            and not self.ask(f"Recording {recording.name}: stop it and close the window?")
        ):
            event.ignore()
            return
        self.timer.stop()
        self.calibrate_tab.stop_capture()
        self.record_tab.close_remote()
        try:
            self.station.shutdown()
        except Exception as exc:  # noqa: BLE001 - shown; the window closes regardless
            self.message(error_line(exc), True)
        while not self.station.finished.empty():
            finished = self.station.finished.get()
            self.message(finished.line())
            for hook in self.finished_hooks:
                hook(finished)
        self.work.shutdown(wait=True)
        super().closeEvent(event)
