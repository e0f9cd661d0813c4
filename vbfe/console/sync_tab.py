"""Sync tab: run the sync protocol session (projector flashes, operator taps) or pick one
recorded before, show the measured offset, its interval, the verdict and the plot; apply the
correction (kept in the rig file for new recordings) and check again."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pyqtgraph.Qt import QtCore, QtGui, QtWidgets

from vbfe.acquire.recording.sync_session import SyncProtocol
from vbfe.common.errors import VbfeError
from vbfe.console.desks import SyncOutcome, apply_sync, check_sync
from vbfe.console.station import Finished
from vbfe.console.widgets import Tab, form, value_label, with_picker
from vbfe.rig_config import RigConfig

if TYPE_CHECKING:
    from vbfe.console.window import ConsoleWindow


class SyncTab(Tab):
    """The protocol's settings, Run and Apply, the report."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__(console)
        layout = QtWidgets.QVBoxLayout(self)
        self.path = QtWidgets.QLineEdit(str(console.options.out_dir / "sync_protocol.h5"))
        self.taps = QtWidgets.QSpinBox()
        self.taps.setRange(1, 200)
        self.taps.setValue(20)
        self.flashes = QtWidgets.QSpinBox()
        self.flashes.setRange(1, 200)
        self.flashes.setValue(20)
        self.duration = QtWidgets.QDoubleSpinBox()
        self.duration.setRange(3.0, 600.0)
        self.duration.setValue(20.0)
        self.duration.setSuffix(" s")
        layout.addLayout(
            form(
                [
                    ("session file", with_picker(self.path, "save", "sync session")),
                    ("taps", self.taps),
                    ("flashes", self.flashes),
                    ("duration", self.duration),
                ]
            )
        )
        buttons = QtWidgets.QHBoxLayout()
        self.run_button = QtWidgets.QPushButton("Run sync protocol")
        self.run_button.clicked.connect(self.run)
        self.apply_button = QtWidgets.QPushButton("Apply correction")
        self.apply_button.clicked.connect(self.apply)
        self.apply_button.setEnabled(False)
        self.check_button = QtWidgets.QPushButton("Check the session file")
        self.check_button.setToolTip("verify-sync of a sync protocol session recorded before")
        self.check_button.clicked.connect(self.check_existing)
        buttons.addWidget(self.run_button)
        buttons.addWidget(self.check_button)
        buttons.addWidget(self.apply_button)
        layout.addLayout(buttons)
        self.busy_bar = QtWidgets.QProgressBar()  # moving while a check or apply runs
        self.busy_bar.setRange(0, 0)
        self.busy_bar.setTextVisible(False)
        self.busy_bar.hide()
        layout.addWidget(self.busy_bar)
        self.progress = value_label()
        layout.addWidget(self.progress)
        self.report = value_label()
        layout.addWidget(self.report)
        self.figure = QtWidgets.QLabel()  # verify-sync's plot, at its own size
        scroll = QtWidgets.QScrollArea()
        scroll.setWidget(self.figure)
        scroll.setWidgetResizable(True)
        layout.addWidget(scroll, 1)
        self.session: Path | None = None
        self.outcome: SyncOutcome | None = None
        self.working = ""  # what runs off the UI thread ("" when nothing)
        self._clock = QtCore.QElapsedTimer()

    def run(self) -> None:
        """Record the protocol session (it ends at its duration), then check it."""
        try:
            protocol = SyncProtocol(
                taps=self.taps.value(),
                flashes=self.flashes.value(),
                duration_s=self.duration.value(),
            )
        except VbfeError as exc:
            self.console.message(f"sync protocol: {exc}", True)
            return
        self.outcome = None
        self.apply_button.setEnabled(False)
        self.report.setText(protocol.instructions())
        self.console.rig_op(
            self.station.start_sync_protocol,
            protocol,
            Path(self.path.text().strip()),
            on_done=self._started,
            what="sync protocol",
        )

    def _started(self, path: Path) -> None:
        self.session = path

    def on_finished(self, finished: Finished) -> None:
        if finished.path != self.session or self.outcome is not None:
            return
        self._work(f"recorded {finished.line()}; checking the sync", check_sync, finished.path)

    def check_existing(self) -> None:
        """verify-sync of the session file named in the form (recorded before)."""
        path = Path(self.path.text().strip())
        if not path.is_file():
            self.console.message(
                f"{path} does not exist: pick a recorded sync session in 'session file'", True
            )
            return
        self.outcome, self.session = None, path
        self.apply_button.setEnabled(False)
        self._work(f"checking {path.name}", check_sync, path)

    def apply(self) -> None:
        """Store the measured offset as the correction (session and new recordings)."""
        if self.outcome is None:
            return
        self.apply_button.setEnabled(False)
        self._work("applying the correction and checking again", apply_sync, self.outcome)

    def _work(self, what: str, fn: Callable[[RigConfig, Any], SyncOutcome], arg: Any) -> None:
        self.working = what
        self._clock.start()
        self.busy_bar.show()
        self.console.work_op(
            fn,
            self.station.config,
            arg,
            on_done=self.show,
            what="verify-sync",
            on_error=self._failed,
        )

    def _failed(self) -> None:
        self.working = ""
        self.busy_bar.hide()
        self.progress.setText(f"sync not checked: {self.console.message_label.text()}")

    def show(self, outcome: SyncOutcome) -> None:
        """The report and plot (and, once applied, the check after the correction)."""
        self.working = ""
        self.busy_bar.hide()
        self.outcome = outcome
        r = outcome.report
        e = r.estimate
        lines = [
            f"offset (image - force) {e.offset_s * 1e3:+.2f} ms, 95% interval "
            f"[{e.ci95_s[0] * 1e3:+.2f}, {e.ci95_s[1] * 1e3:+.2f}] ms",
            f"verdict {r.verdict}" + (": " + "; ".join(r.reasons) if r.reasons else ""),
        ]
        if outcome.applied is not None and outcome.after is not None:
            a, applied = outcome.after, outcome.applied
            lines += [
                f"applied: frame-time correction {applied.correction_s * 1e3:+.2f} ms (this "
                "session and new recordings)",
                f"after the correction: residual {a.estimate.offset_s * 1e3:+.2f} ms, verdict "
                f"{a.verdict}" + (": " + "; ".join(a.reasons) if a.reasons else ""),
            ]
        else:
            self.apply_button.setEnabled(True)
        self.report.setText("\n".join(lines))
        self.progress.setText(f"sync protocol: {outcome.verdict}")
        self.console.message(f"sync: {outcome.verdict}")
        plot = r.plot_path
        if plot is not None and plot.is_file():
            self.figure.setPixmap(QtGui.QPixmap(str(plot)))
        if outcome.applied is not None:
            self.console.settled(correction_s=outcome.applied.correction_s)

    def refresh(self) -> None:
        protocol = self.station.protocol
        recording = self.station.recording
        self.run_button.setEnabled(recording is None and not self.working)
        self.check_button.setEnabled(not self.working)
        self.run_button.setToolTip(
            f"greyed: {recording.name} is being recorded; stop it on the Record tab"
            if recording is not None and protocol is None
            else ""
        )
        if recording is not None and protocol is None and self.isVisible():
            self.progress.setText(
                f"Run is greyed: {recording.name} is being recorded; stop it on the Record tab"
            )
        if self.working:
            self.progress.setText(f"{self.working}… {self._clock.elapsed() / 1e3:.0f} s")
        elif protocol is not None:
            stats = self.station.stats()
            elapsed = stats.elapsed_s if stats is not None else 0.0
            self.progress.setText(
                f"recording the protocol: {elapsed:.1f} of {protocol.duration_s:g} s, "
                f"{protocol.progress()}"
            )
