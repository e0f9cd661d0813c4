"""Calibrate tab: the board (ChArUco or chessboard) and the views folder (captured here or
any layout ``calibrate stereo`` takes), swap eyes, fixed intrinsics; board views captured from
the live frames (the simulated bench shows the board by itself) with the detected corners and
the coverage map; Calibrate runs the stereo calibration off the UI thread and shows RMS, the
report's per-view error, coverage and uncertainty figures and the GO/NO-GO against the stored
calibration; the YAML is written under the CLI's output policy."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from pyqtgraph.Qt import QtCore, QtGui, QtWidgets

from vbfe.calib.board import TARGETS, BoardSpec
from vbfe.calib.capture import annotate, coverage_text
from vbfe.calib.commands import board_spec
from vbfe.calib.report import gate_lines, summary_rows
from vbfe.common.errors import VbfeError
from vbfe.console.desks import CalibrationOutcome, LiveCapture, calibrate
from vbfe.console.widgets import ImagePane, Tab, form, readonly_table, value_label, with_picker

if TYPE_CHECKING:
    from vbfe.console.window import ConsoleWindow

VIEW_COLUMNS = ("view", "RMS left / right / stereo (px)", "status")
DICTIONARIES = tuple(sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_")))
_CELL_PX = 60  # the coverage map's cells as drawn


def coverage_picture(grid: np.ndarray) -> np.ndarray:
    """The capture's coverage grid (kept corners per image region) as a BGR picture with the
    count written in each cell (red: none yet)."""
    rows, cols = grid.shape
    level = (255 * grid / max(int(grid.max()), 1)).astype(np.uint8)
    big = np.kron(level, np.ones((_CELL_PX, _CELL_PX), np.uint8))
    picture = cv2.applyColorMap(255 - big, cv2.COLORMAP_BONE)
    for (r, c), n in np.ndenumerate(grid):
        cv2.putText(
            picture,
            str(int(n)),
            (c * _CELL_PX + 8, r * _CELL_PX + 38),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.8,
            (0, 0, 200) if n == 0 else (0, 0, 0),
            2,
        )
    cv2.rectangle(picture, (0, 0), (cols * _CELL_PX - 1, rows * _CELL_PX - 1), (0, 0, 0), 1)
    return picture


class BoardForm(QtWidgets.QWidget):
    """The ``[calib]`` board as fields: target, squares (with the inner corners a chessboard's
    detector counts), square and marker size, dictionary; every change goes into the rig
    config (a bad value: a message naming the field)."""

    def __init__(self, tab: CalibrateTab) -> None:
        super().__init__()
        self.tab = tab
        spec = board_spec(tab.station.config)
        self.target = QtWidgets.QComboBox()
        self.target.addItems(TARGETS)
        self.target.setCurrentText(spec.target)
        self.squares_x, self.squares_y = QtWidgets.QSpinBox(), QtWidgets.QSpinBox()
        for count, n in ((self.squares_x, spec.squares_x), (self.squares_y, spec.squares_y)):
            count.setRange(2, 99)
            count.setValue(n)
        self.corners = QtWidgets.QLabel()
        self.square_mm, self.marker_mm = QtWidgets.QDoubleSpinBox(), QtWidgets.QDoubleSpinBox()
        for size, metres in ((self.square_mm, spec.square_m), (self.marker_mm, spec.marker_m)):
            size.setRange(0.01, 1000.0)
            size.setDecimals(3)
            size.setSuffix(" mm")
            size.setValue(metres * 1e3)
        self.dictionary = QtWidgets.QComboBox()
        self.dictionary.addItems(DICTIONARIES)
        self.dictionary.setCurrentText(spec.dictionary)
        self.min_views = QtWidgets.QSpinBox()
        self.min_views.setRange(1, 999)
        self.min_views.setValue(tab.station.config.calib.min_views)
        squares = QtWidgets.QHBoxLayout()
        squares.addWidget(self.squares_x)
        squares.addWidget(QtWidgets.QLabel("×"))
        squares.addWidget(self.squares_y)
        squares.addWidget(self.corners, 1)
        squares_row = QtWidgets.QWidget()
        squares_row.setLayout(squares)
        squares.setContentsMargins(0, 0, 0, 0)
        layout = form(
            [
                ("board", self.target),
                ("squares", squares_row),
                ("square size", self.square_mm),
                ("marker size (ChArUco)", self.marker_mm),
                ("dictionary (ChArUco)", self.dictionary),
                ("fewest views", self.min_views),
            ]
        )
        self.setLayout(layout)
        self.target.currentTextChanged.connect(self.changed)
        self.dictionary.currentTextChanged.connect(self.changed)
        for box in (self.squares_x, self.squares_y, self.square_mm, self.marker_mm, self.min_views):
            box.valueChanged.connect(self.changed)
        self.changed()

    def spec(self) -> BoardSpec:
        """The board the fields describe (validated: a bad value raises, naming it)."""
        return BoardSpec(
            squares_x=self.squares_x.value(),
            squares_y=self.squares_y.value(),
            square_m=self.square_mm.value() * 1e-3,
            marker_m=self.marker_mm.value() * 1e-3,
            dictionary=self.dictionary.currentText(),
            legacy=self.tab.station.config.calib.legacy,
            target=self.target.currentText(),
        )

    def show_config(self) -> None:
        """Show the rig configuration's board and fewest views in the fields (one change)."""
        spec, fields = board_spec(self.tab.station.config), self.fields()
        for field in fields:
            field.blockSignals(True)
        self.target.setCurrentText(spec.target)
        self.squares_x.setValue(spec.squares_x)
        self.squares_y.setValue(spec.squares_y)
        self.square_mm.setValue(spec.square_m * 1e3)
        self.marker_mm.setValue(spec.marker_m * 1e3)
        self.dictionary.setCurrentText(spec.dictionary)
        self.min_views.setValue(self.tab.station.config.calib.min_views)
        for field in fields:
            field.blockSignals(False)
        self.changed()

    def fields(self) -> tuple[QtWidgets.QWidget, ...]:
        """The board's input fields."""
        return (
            self.target,
            self.squares_x,
            self.squares_y,
            self.square_mm,
            self.marker_mm,
            self.dictionary,
            self.min_views,
        )

    def changed(self) -> None:
        """Put the fields into the rig config's ``[calib]``; say what is wrong with them."""
        charuco = self.target.currentText() == "charuco"
        self.marker_mm.setEnabled(charuco)
        self.dictionary.setEnabled(charuco)
        nx, ny = self.squares_x.value() - 1, self.squares_y.value() - 1
        self.corners.setText(
            f"inner corners = squares − 1: {nx} × {ny}"
            + ("" if charuco else " (what a chessboard detector counts, e.g. 9 × 6)")
        )
        try:
            calib = {**self.spec().calib_table(), "min_views": self.min_views.value()}
            self.tab.station.reconfigure({"calib": calib})
        except VbfeError as exc:
            self.tab.console.message(f"board: {exc}", True)


class CalibrateTab(Tab):
    """Board and folder settings, capture controls over the annotated view and the coverage
    map, or the calibration's report figures; the result's numbers below."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__(console)
        out = console.options.out_dir
        layout = QtWidgets.QVBoxLayout(self)
        settings = QtWidgets.QHBoxLayout()
        self.folder = QtWidgets.QLineEdit(str(out / "calib-views"))
        self.folder.setToolTip(
            "captured views, or any folder 'calibrate stereo' takes: left/NAME + right/NAME, "
            "NAME_left + NAME_right, leftNN + rightNN, ..."
        )
        self.out = QtWidgets.QLineEdit(str(out / "endoscope.yaml"))
        self.swap_eyes = QtWidgets.QCheckBox("swap eyes (the files' left is the right eye)")
        self.left_camera, self.right_camera = QtWidgets.QLineEdit(), QtWidgets.QLineEdit()
        for edit in (self.left_camera, self.right_camera):
            edit.setPlaceholderText("none: solved with the stereo pair")
        settings.addLayout(
            form(
                [
                    ("views folder", with_picker(self.folder, "folder", "views folder")),
                    ("calibration file", with_picker(self.out, "save", "calibration file")),
                    ("", self.swap_eyes),
                    ("fixed intrinsics, left", with_picker(self.left_camera, "open")),
                    ("fixed intrinsics, right", with_picker(self.right_camera, "open")),
                ]
            ),
            3,
        )
        self.board = BoardForm(self)
        settings.addWidget(self.board, 2)
        layout.addLayout(settings)
        self.pages = QtWidgets.QStackedWidget()  # capture (preview, coverage) or report
        panes = QtWidgets.QWidget()
        pane_layout = QtWidgets.QHBoxLayout(panes)
        pane_layout.setContentsMargins(0, 0, 0, 0)
        self.view = ImagePane(1)
        pane_layout.addWidget(self.view, 3)
        self.map_view = ImagePane(1)  # coverage: kept corners per region of the image
        pane_layout.addWidget(self.map_view, 2)
        self.pages.addWidget(panes)
        self.figures = QtWidgets.QLabel()  # the report's figures at their own size
        report_scroll = QtWidgets.QScrollArea()
        report_scroll.setWidget(self.figures)
        report_scroll.setWidgetResizable(True)
        self.pages.addWidget(report_scroll)
        layout.addWidget(self.pages, 4)
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
        results = QtWidgets.QHBoxLayout()
        results.addWidget(scroll, 3)
        self.views = readonly_table(VIEW_COLUMNS)  # per view: click to see it
        self.views.setSelectionBehavior(QtWidgets.QAbstractItemView.SelectionBehavior.SelectRows)
        self.views.setToolTip("click a view to see it with its corners, and why it was refused")
        self.views.cellClicked.connect(lambda row, _: self.show_view(row))
        results.addWidget(self.views, 2)
        layout.addLayout(results, 2)
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
            self.capture = LiveCapture(self.station.config, folder)  # the board as set now
        except VbfeError as exc:
            self.console.message(f"cannot capture: {exc}", True)
            self.capture_button.setChecked(False)
            return
        if self.station.recording is not None:
            self.console.message("stop the recording first: views come from the live view", True)
            self.capture_button.setChecked(False)
            return
        # the board is seen in room light: the live view restarts with the projector dark
        # (the simulated bench shows the board)
        self._starting = True
        self.pages.setCurrentIndex(0)
        self.console.rig_op(
            self.station.go_live,
            False,
            True,
            on_done=self._start_capture,
            what="opening the rig",
            on_error=self._capture_failed,
        )

    def _start_capture(self, _: None) -> None:
        self._starting = False
        if self.station.board_scene:
            self.console.message(
                "simulated bench: it shows the board set on this tab while capturing "
                "(the Rig tab's Open rig shows the tissue again)"
            )
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

    def intrinsics(self) -> tuple[Path, Path] | None:
        """The fixed intrinsics' camera files (left, right), or ``None`` to solve them."""
        left, right = self.left_camera.text().strip(), self.right_camera.text().strip()
        if not left and not right:
            return None
        if not (left and right):
            raise VbfeError(
                "fixed intrinsics need both camera files: fill in both 'fixed intrinsics' "
                "fields, or empty both to solve them"
            )
        return Path(left), Path(right)

    def calibrate(self) -> None:
        """Calibrate from the views folder off the UI thread."""
        self.stop_capture()
        try:
            intrinsics = self.intrinsics()
        except VbfeError as exc:
            self.console.message(f"calibration refused: {exc}", True)
            return
        self.result_text.setText("calibrating…")
        self.calibrate_button.setEnabled(False)
        self.console.work_op(
            calibrate,
            self.station.config,
            Path(self.folder.text().strip()),
            Path(self.out.text().strip()),
            self.console.options.stored_calibration,
            self.console.options.overwrite,
            self.swap_eyes.isChecked(),
            intrinsics,
            on_done=self.show_outcome,
            what="calibration refused",
            on_error=self._refused,
        )

    def _refused(self) -> None:
        self.calibrate_button.setEnabled(True)
        self.result_text.setText(f"not calibrated: {self.console.message_label.text()}")

    def show_outcome(self, outcome: CalibrationOutcome) -> None:
        """The calibration's numbers, the report's figures and the go/no-go."""
        self.calibrate_button.setEnabled(True)
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
            lines.append("GO/NO-GO: no stored calibration (load one on the Live tab)")
        self.result_text.setText("\n".join(lines))
        self.show_view_rows(outcome)
        self.show_figures(outcome)
        self.console.message(f"calibrated: {outcome.outcome.yaml_path}")
        self.console.settled(calibration=outcome.outcome.yaml_path, board=self.board.spec())

    def show_view_rows(self, outcome: CalibrationOutcome) -> None:
        """One row per view of the folder: its errors when used, else why it was refused."""
        rows = outcome.view_rows()
        self.views.setRowCount(len(rows))
        for r, row in enumerate(rows):
            rms = " / ".join(f"{v:.2f}" for v in row.rms_px) if row.rms_px else "-"
            for c, text in enumerate((row.name, rms, row.status)):
                item = QtWidgets.QTableWidgetItem(text)
                item.setToolTip(text)
                if row.rms_px is None:
                    item.setForeground(QtGui.QColor("#c00000"))
                self.views.setItem(r, c, item)
        self.views.resizeColumnsToContents()
        refused = sum(row.rms_px is None for row in rows)
        self.capture_text.setText(
            f"{refused} of {len(rows)} views refused; click a view (right) to see it with the "
            "corners found and its error, or why it was refused"
        )

    def show_view(self, row: int) -> None:
        """The clicked view with the corners found in each eye, and its errors or why it was
        refused."""
        if self.outcome is None:
            return
        view = self.outcome.view_rows()[row]
        self.view.show_bgr(0, self.outcome.view_picture(view.name))
        rms = (
            f"RMS left {view.rms_px[0]:.2f}, right {view.rms_px[1]:.2f}, stereo "
            f"{view.rms_px[2]:.2f} px"
            if view.rms_px
            else ""
        )
        self.capture_text.setText(f"view {view.name}: {view.status}" + (f"; {rms}" if rms else ""))
        self.pages.setCurrentIndex(0)

    def show_figures(self, outcome: CalibrationOutcome) -> None:
        """The report's figures (per-view error, corner coverage, rectified pair; depth
        uncertainty and board coverage per region) one above the other, at their own size."""
        stem = outcome.outcome.yaml_path.with_suffix("")
        paths = [stem.with_suffix(".png"), stem.parent / f"{stem.name}_uncertainty.png"]
        images = [QtGui.QImage(str(p)) for p in paths if p.is_file()]
        images = [image for image in images if not image.isNull()]
        if not images:
            return
        width = max(image.width() for image in images)
        height = sum(image.height() for image in images)
        canvas = QtGui.QPixmap(width, height)
        canvas.fill(QtGui.QColor("white"))
        painter = QtGui.QPainter(canvas)
        y = 0
        for image in images:
            painter.drawImage(0, y, image)
            y += image.height()
        painter.end()
        self.figures.setPixmap(canvas)
        self.figures.setAlignment(QtCore.Qt.AlignmentFlag.AlignHCenter)
        self.pages.setCurrentIndex(1)

    def refresh(self) -> None:
        capture = self.capture
        running = capture is not None and capture.running()
        if running and self.station.ended():  # the live view stopped: no new frames come
            self.stop_capture()
            self.console.message("capture stopped: the rig stopped; reopen it on the Rig tab", True)
        if self.capture_button.isChecked() and not running and not self._starting:
            self.capture_button.setChecked(False)  # enough views
        if capture is None or not self.isVisible():
            if capture is None and self.outcome is None:
                self.capture_text.setText(
                    "no views captured yet: show the board and press Capture views, or give a "
                    "folder of views and press Calibrate"
                )
            return
        last = capture.last
        if last is not None and last is not self._shown:
            verdict, left = last
            coverage = capture.collector.coverage()
            shown = annotate(left, verdict.left, coverage) if verdict.left is not None else left
            self.view.show_bgr(0, shown)
            grid = capture.collector.coverage_map((left.shape[1], left.shape[0]))
            self.map_view.show_bgr(0, coverage_picture(grid))
            self._shown = last
            reasons = ", ".join(f"{k}: {n}" for k, n in capture.rejections.most_common())
            self.capture_text.setText(
                f"{verdict.reason}\n"
                f"{coverage_text(coverage, capture.kept)}\n"
                f"kept {capture.kept} of {capture.offered} offered"
                + (f" | rejected: {reasons}" if reasons else "")
                + (" | enough views: Calibrate" if capture.collector.enough else "")
            )
