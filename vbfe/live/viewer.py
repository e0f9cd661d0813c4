"""The live estimation window: the estimate (with its prediction interval as a band, frames
outside the training data marked) over the trocar's force on one time axis, with rate,
latency and skipped frames in view. Everything Qt runs on the GUI thread (a timer polls
the run), so the estimator threads never touch a widget."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from pyqtgraph.Qt import QtCore, QtGui, QtWidgets

from vbfe.live.run import LiveRun, LiveStatus

WINDOW_S = 10.0


class LiveEstimateWindow(QtWidgets.QWidget):
    """Plot of the last ``WINDOW_S`` seconds and a status line; closes at ``duration_s``. The
    M key puts an event mark ("key M <n>") into the recording (``vbfe live --record``)."""

    def __init__(
        self, run: LiveRun, duration_s: float | None = None, interval_ms: int = 100
    ) -> None:
        QtWidgets.QApplication.instance() or QtWidgets.QApplication([])
        super().__init__()
        self.run, self.duration_s = run, duration_s
        self.setWindowTitle("vbfe live — force estimate")
        self.resize(900, 500)
        layout = QtWidgets.QVBoxLayout(self)
        self.plot = pg.PlotWidget(background="w")
        self.plot.setLabel("left", f"force ({run.target})", units="N")
        self.plot.setLabel("bottom", "time before now", units="s")
        self.plot.addLegend(offset=(5, 5))
        self.trocar = self.plot.plot(pen=pg.mkPen("#4363d8", width=2), name="trocar")
        self.lo = self.plot.plot(pen=pg.mkPen("#e6194b", width=1, style=QtCore.Qt.PenStyle.DotLine))
        self.hi = self.plot.plot(pen=pg.mkPen("#e6194b", width=1, style=QtCore.Qt.PenStyle.DotLine))
        self.band = pg.FillBetweenItem(self.lo, self.hi, brush=pg.mkBrush(230, 25, 75, 50))
        self.plot.addItem(self.band)
        self.estimate = self.plot.plot(
            pen=None, symbol="o", symbolSize=5, symbolBrush="#e6194b", name="estimate"
        )
        self.flagged = self.plot.plot(
            pen=None,
            symbol="x",
            symbolSize=9,
            symbolPen=pg.mkPen("k"),
            name="outside the training data",
        )
        self.plot.setXRange(-WINDOW_S, 0.0)
        layout.addWidget(self.plot)
        self.status_label = QtWidgets.QLabel()
        layout.addWidget(self.status_label)
        self.last_status: LiveStatus | None = None
        self.marks = 0
        self.note = ""
        self.timer = QtCore.QTimer(self)
        self.timer.timeout.connect(self.refresh)
        self.timer.start(interval_ms)

    def refresh(self) -> None:
        """Redraw from the run's current state; close when the run has ended."""
        curves = self.run.curves(WINDOW_S)
        self.trocar.setData(curves.t_trocar_s, curves.trocar_n)
        self.estimate.setData(curves.t_estimate_s, curves.estimate_n)
        banded = np.isfinite(curves.lo_n) & np.isfinite(curves.hi_n)
        self.lo.setData(curves.t_estimate_s[banded], curves.lo_n[banded])
        self.hi.setData(curves.t_estimate_s[banded], curves.hi_n[banded])
        flagged = curves.ood
        self.flagged.setData(curves.t_estimate_s[flagged], curves.estimate_n[flagged])
        self.last_status = self.run.status()
        self.status_label.setText(self.last_status.line() + self.note)
        done = self.duration_s is not None and self.last_status.wall_s >= self.duration_s
        if done or not self.run.running():
            self.close()

    def keyPressEvent(self, event: QtGui.QKeyEvent) -> None:  # noqa: N802 - Qt's name
        """M marks an event in the recording."""
        if event.key() != QtCore.Qt.Key.Key_M:
            super().keyPressEvent(event)
            return
        if self.run.mark(f"key M {self.marks + 1}"):
            self.marks += 1
            self.note = f" | mark {self.marks}"
        else:
            self.note = " | marks need --record"

    def closeEvent(self, event: object) -> None:  # noqa: N802 - Qt's name
        """Stop polling when the window goes."""
        self.timer.stop()
        super().closeEvent(event)


def show_live(run: LiveRun, duration_s: float | None) -> LiveStatus:
    """Run the window until it is closed (or ``duration_s``), then stop the run."""
    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication([])
    window = LiveEstimateWindow(run, duration_s)
    window.show()
    app.exec()
    window.deleteLater()
    QtWidgets.QApplication.sendPostedEvents(None, 0)
    return run.stop(
        "window closed"
        if window.last_status is None
        or duration_s is None
        or window.last_status.wall_s < duration_s
        else "duration reached"
    )
