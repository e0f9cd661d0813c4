"""Sync tab: run the sync protocol session (projector flashes, operator taps), show the
measured offset, its interval and the verdict; apply the correction and check again."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from pyqtgraph.Qt import QtWidgets

from vbfe.acquire.recording.sync_session import SyncProtocol
from vbfe.common.errors import VbfeError
from vbfe.console.desks import SyncOutcome, apply_sync, check_sync
from vbfe.console.station import Finished
from vbfe.console.widgets import Tab, form, value_label

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
                    ("session file", self.path),
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
        buttons.addWidget(self.run_button)
        buttons.addWidget(self.apply_button)
        layout.addLayout(buttons)
        self.progress = value_label()
        layout.addWidget(self.progress)
        self.report = value_label()
        layout.addWidget(self.report, 1)
        self.session: Path | None = None
        self.outcome: SyncOutcome | None = None

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
        self.progress.setText(f"recorded {finished.line()}; checking…")
        self.console.work_op(
            check_sync, self.station.config, finished.path, on_done=self.show, what="verify-sync"
        )

    def apply(self) -> None:
        """Store the measured offset as the correction (session and new recordings)."""
        if self.outcome is None:
            return
        self.apply_button.setEnabled(False)
        self.console.work_op(
            apply_sync, self.station.config, self.outcome, on_done=self.show, what="apply"
        )

    def show(self, outcome: SyncOutcome) -> None:
        """The report (and, once applied, the check after the correction)."""
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
                f"applied: frame-time correction {applied.correction_s * 1e3:+.2f} ms (new "
                f"recordings too; rig config [record] {applied.config_suggestion()})",
                f"after the correction: residual {a.estimate.offset_s * 1e3:+.2f} ms, verdict "
                f"{a.verdict}" + (": " + "; ".join(a.reasons) if a.reasons else ""),
            ]
        else:
            self.apply_button.setEnabled(True)
        self.report.setText("\n".join(lines))
        self.progress.setText(f"sync protocol: {outcome.verdict}")
        self.console.message(f"sync: {outcome.verdict}")

    def refresh(self) -> None:
        protocol = self.station.protocol
        busy = self.station.recording is not None
        self.run_button.setEnabled(not busy)
        if protocol is not None:
            stats = self.station.stats()
            elapsed = stats.elapsed_s if stats is not None else 0.0
            self.progress.setText(
                f"recording the protocol: {elapsed:.1f} of {protocol.duration_s:g} s, "
                f"{protocol.progress()}"
            )
