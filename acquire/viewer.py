"""pyqtgraph viewer: left/right images, force plot and drop counters — replay or live.

``ReplayViewer(reader)`` scrubs a recorded session with a time slider;
``LiveViewer(acquisition)`` listens to a running acquisition and scrolls the force plot.
``view_session(path)`` / ``view_live(config)`` run them as applications. Works headless with
``QT_QPA_PLATFORM=offscreen``.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyqtgraph as pg
from pyqtgraph.Qt import QtCore, QtWidgets

from vbfe.acquire.recording.acquisition import Acquisition
from vbfe.acquire.recording.latest import Latest
from vbfe.acquire.session.reader import SessionReader
from vbfe.drivers.qt_app import dispose_widget, qt_application
from vbfe.drivers.samples import StereoFrame

if TYPE_CHECKING:
    from vbfe.drivers.registry import DeviceTables

FORCE_PENS = ("#e6194b", "#3cb44b", "#4363d8")  # x, y, z
STREAM_PENS = ("#f58231", "#911eb4", "#42d4f4", "#f032e6", "#bfef45", "#469990", "#9a6324")
LIVE_WINDOW_S = 10.0


def _rgb(bgr: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(bgr[..., ::-1])


class ViewerWindow(QtWidgets.QWidget):
    """Two image panes over a force plot, with a status line for counters."""

    def __init__(self, title: str, axes: list[str]) -> None:
        qt_application()  # widgets need the application object first
        super().__init__()
        self.setWindowTitle(title)
        self.resize(1000, 650)
        layout = QtWidgets.QVBoxLayout(self)
        images = pg.GraphicsLayoutWidget()
        self.image_items = []
        for _eye in ("left", "right"):
            view = images.addViewBox(lockAspect=True, invertY=True, enableMouse=False)
            item = pg.ImageItem(axisOrder="row-major")
            view.addItem(item)
            self.image_items.append(item)
        layout.addWidget(images, stretch=3)
        self.plot = pg.PlotWidget(background="w")
        self.plot.setLabel("left", "force", units="N")
        self.plot.setLabel("bottom", "time", units="s")
        self.plot.addLegend(offset=(5, 5))
        self.curves = [
            self.plot.plot(pen=pg.mkPen(FORCE_PENS[i % 3], width=2), name=f"F{a}")
            for i, a in enumerate(axes)
        ]
        self.cursor = pg.InfiniteLine(angle=90, pen=pg.mkPen("k", width=1))
        self.plot.addItem(self.cursor)
        layout.addWidget(self.plot, stretch=2)
        self.slider = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        layout.addWidget(self.slider)
        self.status = QtWidgets.QLabel()
        layout.addWidget(self.status)
        self.stream_plots: list[pg.PlotWidget] = []

    def dispose(self) -> None:
        """Close and delete the window now (see :func:`dispose_widget`)."""
        dispose_widget(self)

    def show_images(self, left: np.ndarray, right: np.ndarray) -> None:
        """Display a BGR stereo pair."""
        for item, image in zip(self.image_items, (left, right), strict=False):
            item.setImage(_rgb(image), autoLevels=False, levels=(0, 255))

    def show_force(self, t_s: np.ndarray, forces_n: np.ndarray) -> None:
        """Plot force columns against time (s)."""
        for axis, curve in enumerate(self.curves):
            curve.setData(t_s, forces_n[:, axis])

    def add_stream_plot(
        self, name: str, t_s: np.ndarray, values: np.ndarray, channels: list[str], units: list[str]
    ) -> pg.PlotWidget:
        """A plot of an extra stream's channels under the force, on the same time axis (the
        unit axis is labelled when all channels share one), with its own cursor."""
        plot = pg.PlotWidget(background="w")
        plot.setXLink(self.plot)
        shared = set(units)
        plot.setLabel("left", name, units=shared.pop() if len(shared) == 1 else None)
        plot.addLegend(offset=(5, 5))
        for k, channel in enumerate(channels):
            plot.plot(
                t_s,
                values[:, k],
                pen=pg.mkPen(STREAM_PENS[k % len(STREAM_PENS)], width=1),
                name=channel,
            )
        cursor = pg.InfiniteLine(angle=90, pen=pg.mkPen("k", width=1))
        plot.addItem(cursor)
        self.cursor.sigPositionChanged.connect(lambda line: cursor.setValue(line.value()))
        self.layout().insertWidget(
            self.layout().indexOf(self.plot) + 1 + len(self.stream_plots), plot, stretch=1
        )
        self.stream_plots.append(plot)
        return plot

    def mark_events(self, events: list[tuple[float, str]]) -> None:
        """Vertical labelled lines on the force plot at event times (s)."""
        for t_s, text in events:
            self.plot.addItem(
                pg.InfiniteLine(
                    t_s,
                    angle=90,
                    pen=pg.mkPen("#808080", dash=[4, 4]),
                    label=text,
                    labelOpts={"position": 0.9, "color": "#404040"},
                )
            )


class ReplayViewer(ViewerWindow):
    """Replay a session: the slider picks a frame; the cursor marks its time on the force plot."""

    def __init__(self, reader: SessionReader) -> None:
        super().__init__(f"vbfe view — {reader.path.name}", reader.force_axes)
        self.reader = reader
        self.frame_times_s = (reader.frame_times_ns() - self._t0()) / 1e9
        forces = reader.forces_n()
        if len(forces):
            self.show_force((reader.force_times_ns() - self._t0()) / 1e9, forces)
        for name in reader.stream_names():
            stream = reader.stream(name)
            if stream.values is not None and len(stream):  # a numeric stream
                self.add_stream_plot(
                    name,
                    (stream.t_host_ns - self._t0()) / 1e9,
                    stream.values,
                    stream.channels,
                    stream.units,
                )
        self.mark_events(
            [((e["t_host_ns"] - self._t0()) / 1e9, e["text"]) for e in reader.events()]
        )
        self.slider.setRange(0, max(reader.n_frames - 1, 0))
        self.slider.valueChanged.connect(self.show_frame)
        gaps = len(reader.gaps())
        self._counters = f"{reader.n_frames} frames, {len(forces)} force samples, {gaps} gaps" + (
            " — BEING RECORDED: showing what was flushed when opened"
            if reader.growing
            else ""
            if reader.complete
            else " — NOT CLOSED CLEANLY"
        )
        if reader.n_frames:
            self.show_frame(0)

    def _t0(self) -> int:
        times = [
            t[0] for t in (self.reader.frame_times_ns(), self.reader.force_times_ns()) if len(t)
        ]
        return int(min(times)) if times else 0

    def show_frame(self, i: int) -> None:
        """Show frame ``i`` and move the force cursor to its time."""
        frame = self.reader.frame(i)
        self.show_images(frame.left, frame.right)
        self.cursor.setValue(float(self.frame_times_s[i]))
        self.status.setText(
            f"frame {i} (seq {frame.seq}) at {self.frame_times_s[i]:.3f} s — " + self._counters
        )


class LiveViewer(ViewerWindow):
    """Show an acquisition live: newest frame pair, the last seconds of force, drop counters.
    Made before the acquisition starts (it adds its listener)."""

    def __init__(self, acquisition: Acquisition, window_s: float = LIVE_WINDOW_S) -> None:
        trocar = acquisition.rig.trocar
        super().__init__("vbfe view — live", list(trocar.axes))
        self.acquisition = acquisition
        self.slider.hide()
        self._newest = acquisition.add(Latest(window_s))
        self._shown: StereoFrame | None = None
        self.error: str | None = None
        self.timer = QtCore.QTimer(self)
        self.timer.timeout.connect(self.poll)

    def poll(self) -> None:
        """Show what the acquisition has now."""
        reason = self.acquisition.finished()
        if reason and reason != "duration reached":
            self.error = reason
            self.timer.stop()
            self.status.setText(f"device gone: {reason}")
            return
        frame = self._newest.frame
        if frame is not None and frame is not self._shown:
            self.show_images(frame.left, frame.right)
            self._shown = frame
        samples = self._newest.records("force")
        if samples:
            t = np.array([s.t_host_ns for s in samples])
            self.show_force((t - t[-1]) / 1e9, np.array([s.force_n for s in samples]))
            self.cursor.setValue(0.0)
        rig = self.acquisition.rig
        cam, tro = rig.camera.stats, rig.trocar.stats
        self.status.setText(
            f"camera: {cam.received} frames, {cam.dropped} dropped — trocar: "
            f"{tro.received} samples, {tro.dropped} dropped, "
            f"{tro.malformed} malformed"
        )


def grab_png(widget: QtWidgets.QWidget, path: str | Path) -> Path:
    """Render a viewer window into a PNG (works offscreen)."""
    qt_application().processEvents()
    if not widget.grab().save(str(path)):
        raise OSError(f"could not write {path}")
    return Path(path)


def exec_until_closed(
    app: QtWidgets.QApplication,
    window: QtWidgets.QWidget,
    close: Callable[[], object] | None = None,
) -> int:
    """Run the event loop until the window closes, Ctrl-C or SIGTERM (which close it with
    ``close``, default ``window.close``; a timer hands control back to Python regularly so
    that its signal handlers run)."""
    handlers = {}
    close = close or window.close
    if threading.current_thread() is threading.main_thread():
        handlers = {
            sig: signal.signal(sig, lambda *_: close()) for sig in (signal.SIGINT, signal.SIGTERM)
        }
    wake = QtCore.QTimer()
    wake.timeout.connect(lambda: None)
    wake.start(200)
    try:
        return app.exec()
    finally:
        wake.stop()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def view_session(path: str | Path) -> int:
    """Open the replay viewer on a session and run until the window closes."""
    app = qt_application()
    with SessionReader(path) as reader:
        window = ReplayViewer(reader)
        window.show()
        code = exec_until_closed(app, window)
        window.dispose()
        return code


def view_live(config: DeviceTables, interval_ms: int = 30) -> int:
    """Open the camera and trocar of a rig and show them live until the window closes."""
    from vbfe.drivers.registry import FAMILIES, open_rig

    app = qt_application()
    acquisition = Acquisition(
        open_rig(config, families=tuple(f for f in FAMILIES if f != "projector"))
    )
    window = LiveViewer(acquisition)
    acquisition.start()
    try:
        window.show()
        window.timer.start(interval_ms)
        code = exec_until_closed(app, window)
        window.timer.stop()
        window.dispose()
        return code
    finally:
        acquisition.stop("window closed")
