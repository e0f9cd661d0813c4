"""Calibrate tab: board views captured from the live frames with the detected corners drawn,
the coverage bars and map, why views were rejected, the kept count; Calibrate runs the stereo
calibration off the UI thread and shows RMS, per-view error and the GO/NO-GO against the stored
calibration; the YAML is written under the CLI's output policy."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyqtgraph as pg
from pyqtgraph.Qt import QtGui, QtWidgets

from vbfe.calib.capture import annotate, coverage_text
from vbfe.calib.report import gate_lines, summary_rows
from vbfe.common.errors import VbfeError
from vbfe.console.desks import CalibrationOutcome, LiveCapture, calibrate
from vbfe.console.widgets import ImagePane, Tab, form, value_label

if TYPE_CHECKING:
    from vbfe.console.window import ConsoleWindow


class CalibrateTab(Tab):
    """Capture controls over the annotated view and the coverage map; the result below."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__(console)
        out = console.options.out_dir
        layout = QtWidgets.QVBoxLayout(self)
        self.folder = QtWidgets.QLineEdit(str(out / "calib-views"))
        self.out = QtWidgets.QLineEdit(str(out / "endoscope.yaml"))
        layout.addLayout(form([("views folder", self.folder), ("calibration file", self.out)]))
        panes = QtWidgets.QHBoxLayout()
        self.view = ImagePane(1)
        panes.addWidget(self.view, 3)
        self.map_widget = pg.GraphicsLayoutWidget()
        self.map_widget.addLabel("coverage map: kept corners per region of the image")
        self.map_widget.nextRow()
        self.map_view = self.map_widget.addViewBox(lockAspect=True, invertY=True, enableMouse=False)
        self.map_image = pg.ImageItem(axisOrder="row-major")
        self.map_view.addItem(self.map_image)
        self.map_widget.nextRow()
        self.sigma_label = self.map_widget.addLabel("depth uncertainty: calibrate to see it")
        self.map_widget.nextRow()
        self.sigma_view = self.map_widget.addViewBox(
            lockAspect=True, invertY=True, enableMouse=False
        )
        self.sigma_image = pg.ImageItem(axisOrder="row-major")
        self.sigma_view.addItem(self.sigma_image)
        panes.addWidget(self.map_widget, 2)
        layout.addLayout(panes, 3)
        buttons = QtWidgets.QHBoxLayout()
        self.capture_button = QtWidgets.QPushButton("Capture views")
        self.capture_button.setCheckable(True)
        self.capture_button.toggled.connect(self.toggle_capture)
        self.calibrate_button = QtWidgets.QPushButton("Calibrate")
        self.calibrate_button.clicked.connect(self.calibrate)
        buttons.addWidget(self.capture_button)
        buttons.addWidget(self.calibrate_button)
        layout.addLayout(buttons)
        self.capture_text = value_label()
        layout.addWidget(self.capture_text)
        self.result_text = value_label()  # fixed width: the CLI's aligned rows and gates
        self.result_text.setFont(
            QtGui.QFontDatabase.systemFont(QtGui.QFontDatabase.SystemFont.FixedFont)
        )
        scroll = QtWidgets.QScrollArea()  # the result's rows scroll; the panes keep their room
        scroll.setWidgetResizable(True)
        scroll.setWidget(self.result_text)
        layout.addWidget(scroll, 2)
        self.capture: LiveCapture | None = None
        self.outcome: CalibrationOutcome | None = None
        self._shown: object = None  # the verdict on view
        self._starting = False  # the live view is being reopened for the capture

    def toggle_capture(self, on: bool) -> None:
        """Start or stop offering the live frames as board views."""
        if not on:
            self.stop_capture()
            return
        folder = Path(self.folder.text().strip())
        try:
            if self.capture is None or self.capture.folder != folder:
                self.capture = LiveCapture(self.station.config, folder)
        except VbfeError as exc:
            self.console.message(f"cannot capture: {exc}", True)
            self.capture_button.setChecked(False)
            return
        if self.station.recording is not None:
            self.console.message("stop the recording first: views come from the live view", True)
            self.capture_button.setChecked(False)
            return
        # the board is seen in room light: the live view restarts with the projector dark
        self._starting = True
        self.console.rig_op(
            self.station.go_live,
            False,
            on_done=self._start_capture,
            what="opening the rig",
            on_error=self._capture_failed,
        )

    def _start_capture(self, _: None) -> None:
        self._starting = False
        if self.capture is not None and self.capture_button.isChecked():
            self.capture.start(self.station.latest)

    def _capture_failed(self) -> None:
        self._starting = False
        self.capture_button.setChecked(False)

    def stop_capture(self) -> None:
        """Stop offering frames (the live view keeps the projector dark until reopened)."""
        if self.capture is not None:
            self.capture.stop()
        if self.capture_button.isChecked():
            self.capture_button.setChecked(False)

    def calibrate(self) -> None:
        """Calibrate from the views folder off the UI thread."""
        self.stop_capture()
        stored = self.console.options.stored_calibration
        self.result_text.setText("calibrating…")
        self.console.work_op(
            calibrate,
            self.station.config,
            Path(self.folder.text().strip()),
            Path(self.out.text().strip()),
            stored,
            self.console.options.overwrite,
            on_done=self.show_outcome,
            what="calibration refused",
        )

    def show_outcome(self, outcome: CalibrationOutcome) -> None:
        """The calibration's numbers and the go/no-go."""
        self.outcome = outcome
        result = outcome.outcome.result
        c = result.calibration
        per_view = outcome.per_view_rms_px()
        rows = summary_rows(c)  # as `vbfe calibrate stereo` prints them
        width = max(len(label) for label, _ in rows)
        lines = [
            f"wrote {outcome.outcome.yaml_path}"
            + (
                f", report {outcome.outcome.report_paths[1]}"
                if outcome.outcome.report_paths
                else ""
            ),
            f"views used {len(result.names)}",
            *(f"{label:<{width}}  {value}" for label, value in rows),
            *gate_lines(c),
            "per-view RMS (left): "
            + ", ".join(f"{name} {rms:.2f}" for name, rms in per_view.items()),
        ]
        if result.dropped:
            lines.append("dropped: " + "; ".join(f"{k}: {v}" for k, v in result.dropped.items()))
        if outcome.check is not None:
            failures = outcome.check.failures()
            lines.append(
                "GO: the stored calibration still holds"
                if not failures
                else "NO-GO: " + "; ".join(failures)
            )
        else:
            lines.append("GO/NO-GO: no stored calibration given (vbfe console --calib FILE)")
        self.result_text.setText("\n".join(lines))
        self.show_uncertainty(outcome)
        self.console.message(f"calibrated: {outcome.outcome.yaml_path}")

    def show_uncertainty(self, outcome: CalibrationOutcome) -> None:
        """The calibration's depth σ over the left image (bright: less certain), as the
        calibration report's uncertainty figure, titled with its range."""
        umap = outcome.outcome.result.uncertainty
        if umap is None:
            return
        sigma_mm = umap.depth_sigma_m * 1e3
        low, high = float(sigma_mm.min()), float(sigma_mm.max())
        self.sigma_image.setImage(sigma_mm, autoLevels=False, levels=(low, max(high, low + 1e-9)))
        self.sigma_label.setText(
            f"depth σ at {umap.working_distance_m * 1e3:.0f} mm, left image: "
            f"{low:.3f} (dark) to {high:.3f} mm"
        )

    def refresh(self) -> None:
        capture = self.capture
        running = capture is not None and capture.running()
        if running and self.station.ended():  # the live view stopped: no new frames come
            self.stop_capture()
            self.console.message("capture stopped: the rig stopped; reopen it on the Rig tab", True)
        if self.capture_button.isChecked() and not running and not self._starting:
            self.capture_button.setChecked(False)  # enough views
        if capture is None or not self.isVisible():
            if capture is None:
                self.capture_text.setText("no views captured yet: show the board and press Capture")
            return
        last = capture.last
        if last is not None and last is not self._shown:
            verdict, left = last
            coverage = capture.collector.coverage()
            shown = annotate(left, verdict.left, coverage) if verdict.left is not None else left
            self.view.show_bgr(0, shown)
            grid = capture.collector.coverage_map((left.shape[1], left.shape[0]))
            self.map_image.setImage(
                (255 * grid / max(int(grid.max()), 1)).astype(np.uint8),
                autoLevels=False,
                levels=(0, 255),
            )
            self._shown = last
            reasons = ", ".join(f"{k}: {n}" for k, n in capture.rejections.most_common())
            self.capture_text.setText(
                f"{verdict.reason}\n"
                f"{coverage_text(coverage, capture.kept)}\n"
                f"kept {capture.kept} of {capture.offered} offered"
                + (f" | rejected: {reasons}" if reasons else "")
                + (" | enough views: Calibrate" if capture.collector.enough else "")
            )
