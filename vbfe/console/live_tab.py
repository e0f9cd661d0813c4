"""Live tab: the calibration and model in use (load, unload, estimate on or off), left and
right images (the De Bruijn decode as an optional overlay), the force trace and numeric streams
on one time axis, and the live estimate's |F| with its 90 % band beside the trocar's |F|, the
frames outside the training data flagged."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyqtgraph as pg
from pyqtgraph.Qt import QtWidgets

from vbfe.acquire.viewer import FORCE_PENS, STREAM_PENS
from vbfe.console.widgets import ImagePane, Tab, value_label, with_picker
from vbfe.drivers import StereoFrame

if TYPE_CHECKING:
    from vbfe.console.window import ConsoleWindow

WINDOW_S = 10.0
BAND_PEN, BAND_BRUSH = (31, 78, 158, 90), (31, 78, 158, 50)  # the estimate's 90 % band
MAX_POINTS = 600  # per curve: about a point per pixel of the plot (painting more costs the UI)
_CORE_STREAMS = ("camera", "force", "projector", "marks")


class LiveTab(Tab):
    """Images over the force plot (seconds before now), streams and estimate below."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__(console)
        layout = QtWidgets.QVBoxLayout(self)
        station = console.station
        self.calibration = QtWidgets.QLineEdit(
            station.calibration_name if station.calibration is not None else ""
        )
        self.calibration.setPlaceholderText("calibration YAML (none loaded)")
        self.model = QtWidgets.QLineEdit(station.model_name)
        self.model.setPlaceholderText("model .pt from vbfe train (none loaded)")
        self.estimate = QtWidgets.QCheckBox("estimate")
        self.estimate.setChecked(station.estimate_on)
        self.estimate.toggled.connect(self.toggle_estimate)
        controls = QtWidgets.QGridLayout()
        rows = (
            ("calibration", self.calibration, self.load_calibration, self.unload_calibration),
            ("model", self.model, self.load_model, self.unload_model),
        )
        self.load_buttons: dict[str, QtWidgets.QPushButton] = {}
        for r, (name, edit, load, unload) in enumerate(rows):
            controls.addWidget(QtWidgets.QLabel(name), r, 0)
            controls.addWidget(with_picker(edit, "open", f"{name} file"), r, 1)
            load_button, unload_button = (
                QtWidgets.QPushButton("Load"),
                QtWidgets.QPushButton("Unload"),
            )
            load_button.clicked.connect(load)
            unload_button.clicked.connect(unload)
            controls.addWidget(load_button, r, 2)
            controls.addWidget(unload_button, r, 3)
            self.load_buttons[name] = load_button
        controls.addWidget(self.estimate, 1, 4)
        controls.setColumnStretch(1, 1)
        layout.addLayout(controls)
        self.images = ImagePane(2)
        layout.addWidget(self.images, 3)
        self.overlay = QtWidgets.QCheckBox("De Bruijn decode overlay (left)")
        layout.addWidget(self.overlay)
        self.force_plot = pg.PlotWidget(background="w")
        self.force_plot.setLabel("left", "force", units="N")
        self.force_plot.setLabel("bottom", "time before now", units="s")
        self.force_plot.addLegend(offset=(5, 5))
        self.force_plot.setXRange(-WINDOW_S, 0.0)
        self.force_curves: list[pg.PlotDataItem] = []
        layout.addWidget(self.force_plot, 2)
        self.magnitude_plot = pg.PlotWidget(background="w")  # estimate against trocar, |F|
        self.magnitude_plot.setXLink(self.force_plot)
        self.magnitude_plot.setLabel("left", "|F|", units="N")
        self.magnitude_plot.addLegend(offset=(5, 5))
        self.trocar_curve = self.magnitude_plot.plot(pen=pg.mkPen("k", width=2), name="trocar |F|")
        self.band_lo = self.magnitude_plot.plot(pen=pg.mkPen(BAND_PEN))
        self.band_hi = self.magnitude_plot.plot(pen=pg.mkPen(BAND_PEN), name="90 % band")
        self.band = pg.FillBetweenItem(self.band_lo, self.band_hi, brush=pg.mkBrush(BAND_BRUSH))
        self.magnitude_plot.addItem(self.band)
        self.estimate_curve = self.magnitude_plot.plot(
            pen=None, symbol="o", symbolSize=5, symbolBrush="#1f4e9e", name="estimate"
        )
        self.ood_curve = self.magnitude_plot.plot(
            pen=None, symbol="x", symbolSize=9, symbolPen="#c00000", name="outside training data"
        )
        layout.addWidget(self.magnitude_plot, 2)
        self.magnitude_plot.hide()  # shown while the estimate runs
        self.stream_plot = pg.PlotWidget(background="w")
        self.stream_plot.setXLink(self.force_plot)
        self.stream_plot.setLabel("left", "streams")
        self.stream_plot.addLegend(offset=(5, 5))
        self.stream_curves: dict[str, pg.PlotDataItem] = {}
        layout.addWidget(self.stream_plot, 1)
        self.status = value_label()
        layout.addWidget(self.status)
        self.flag = value_label()  # the newest estimate's frame is outside the training data
        self.flag.setStyleSheet("color: #ffffff; background: #c00000; padding: 3px")
        self.flag.hide()
        layout.addWidget(self.flag)
        self._shown: StereoFrame | None = None
        self._traces_turn = False
        self._decoding = False
        # the newest decoded left image and its overlay (shown over the newer frames)
        self.decoded: tuple[np.ndarray, np.ndarray] | None = None

    def refresh(self) -> None:
        """Draw the images and the traces on alternate calls: each pass of the event loop
        paints half as much (the UI stays responsive beside a busy recorder)."""
        if not self.isVisible():  # drawing costs the recorder CPU: only the tab in view
            return
        self._traces_turn = not self._traces_turn
        if self._traces_turn:
            self._draw_traces()
            return
        frame = self.station.latest.frame
        if frame is not None and frame is not self._shown:
            left = frame.left
            if self.overlay.isChecked():
                left = self._with_overlay(frame)
            self.images.show_bgr(0, left)
            self.images.show_bgr(1, frame.right)
            self._shown = frame

    def _draw_traces(self) -> None:
        latest = self.station.latest
        samples = thinned(latest.records("force"))
        if samples:
            now = samples[-1].t_host_ns
            t = (np.array([s.t_host_ns for s in samples], np.float64) - now) / 1e9
            forces = np.array([s.force_n for s in samples])
            while len(self.force_curves) < forces.shape[1]:
                k = len(self.force_curves)
                self.force_curves.append(
                    self.force_plot.plot(
                        pen=pg.mkPen(FORCE_PENS[k % 3], width=1), name=f"F{'xyz'[k]}"
                    )
                )
            for k, curve in enumerate(self.force_curves):
                curve.setData(t, forces[:, k])
            self._show_streams(now)
        live = self.station.live
        self.magnitude_plot.setVisible(live is not None)
        if live is not None:
            curves = live.curves(WINDOW_S)
            self.trocar_curve.setData(curves.t_trocar_s, curves.trocar_n)
            self.estimate_curve.setData(curves.t_estimate_s, curves.estimate_n)
            banded = np.isfinite(curves.lo_n) & np.isfinite(curves.hi_n)
            t_band = curves.t_estimate_s[banded]
            self.band_lo.setData(t_band, curves.lo_n[banded])
            self.band_hi.setData(t_band, curves.hi_n[banded])
            self.ood_curve.setData(curves.t_estimate_s[curves.ood], curves.estimate_n[curves.ood])
            flagged = bool(len(curves.ood)) and bool(curves.ood[-1])
            self.flag.setVisible(flagged)
            self.flag.setText(
                "⚠ the newest frame is outside the model's training data: its estimate "
                "may be far off"
            )
            self.status.setText(live.status().line())
        else:
            self.flag.hide()
            stats = self.station.stats()
            station = self.station
            why = (
                "estimate switched off"
                if station.estimator is not None
                else "no model loaded: load a calibration and a model above"
            )
            self.status.setText(
                why + (f" | {stats.frames} frames, {stats.samples} force samples" if stats else "")
            )

    def _show_streams(self, now_ns: int) -> None:
        latest = self.station.latest
        for name in latest.streams():
            if name in _CORE_STREAMS:
                continue
            records = [
                r for r in thinned(latest.records(name)) if getattr(r, "values", None) is not None
            ]
            if not records:
                continue
            t = (np.array([r.t_host_ns for r in records], np.float64) - now_ns) / 1e9
            values = np.array([r.values for r in records], np.float64)
            for k in range(values.shape[1]):
                key = f"{name}[{k}]"
                if key not in self.stream_curves:
                    pen = pg.mkPen(STREAM_PENS[len(self.stream_curves) % len(STREAM_PENS)])
                    self.stream_curves[key] = self.stream_plot.plot(pen=pen, name=key)
                self.stream_curves[key].setData(t, values[:, k])

    # -- calibration and model ----------------------------------------------------------------
    def load_calibration(self) -> None:
        """Use the calibration file in the field (checked against the camera's image size)."""
        path = self._path(self.calibration, "calibration")
        if path is not None:
            self._use(self.station.use_calibration, path, "calibration", calibration=path)

    def unload_calibration(self) -> None:
        """No calibration (and so no estimate)."""
        self._use(self.station.use_calibration, None, "calibration")

    def load_model(self) -> None:
        """Estimate with the model file in the field."""
        path = self._path(self.model, "model")
        if path is not None:
            self._use(self.station.use_model, path, "model", model=path)

    def unload_model(self) -> None:
        """No live estimate."""
        self._use(self.station.use_model, None, "model")

    def toggle_estimate(self, on: bool) -> None:
        """Switch the live estimate on or off."""
        self.console.rig_op(self.station.set_estimate, on, what="estimate")

    def _path(self, edit: QtWidgets.QLineEdit, what: str) -> Path | None:
        text = edit.text().strip()
        if not text:
            self.console.message(f"no {what} file: fill in '{what}' (Live tab)", True)
            return None
        return Path(text)

    def _use(
        self, fn: Callable[[Path | None], None], path: Path | None, what: str, **settled: Path
    ) -> None:
        button = self.load_buttons[what]

        def done(_: None) -> None:
            button.setEnabled(True)
            self.console.message(f"{what} {'loaded: ' + str(path) if path else 'unloaded'}")
            if settled:
                self.console.settled(**settled)  # type: ignore[arg-type]

        button.setEnabled(False)
        self.console.rig_op(
            fn,
            path,
            on_done=done,
            what=f"{what} refused",
            on_error=lambda: button.setEnabled(True),
        )

    def _with_overlay(self, frame: StereoFrame) -> np.ndarray:
        """The left image with the last decoded fringe indices coloured over it; the decode of
        the newest frame runs off the UI thread."""
        if not self._decoding:
            self._decoding = True
            left = frame.left
            self.console.work_op(
                decode_overlay,
                left,
                on_done=lambda overlay: self._overlay_done(left, overlay),
                what="De Bruijn decode",
                on_error=self._overlay_failed,
            )
        if self.decoded is None or self.decoded[1].shape != frame.left.shape:
            return frame.left
        return self.decoded[1]

    def _overlay_done(self, left: np.ndarray, overlay: np.ndarray) -> None:
        self.decoded, self._decoding = (left, overlay), False

    def _overlay_failed(self) -> None:
        self._decoding = False
        self.overlay.setChecked(False)


def thinned(records: list[Any]) -> list[Any]:
    """At most about :data:`MAX_POINTS` of ``records``, evenly spaced, the newest kept."""
    step = len(records) // MAX_POINTS + 1
    return records[::-1][::step][::-1]


def decode_overlay(left: np.ndarray) -> np.ndarray:
    """``left`` blended with a colour per decoded fringe index (undecoded pixels as they are)."""
    import cv2

    from vbfe.recon.decode import FringeDecoder

    index = FringeDecoder().decode(left).index
    valid = index >= 0
    hue = ((index.astype(np.int32) * 37) % 180).astype(np.uint8)
    hsv = np.dstack([hue, np.full_like(hue, 255), np.full_like(hue, 255)])
    colour = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
    out = left.copy()
    out[valid] = (0.5 * left[valid] + 0.5 * colour[valid]).astype(np.uint8)
    return out
