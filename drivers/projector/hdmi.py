"""A projector on an HDMI output: a borderless full-screen Qt window showing the pattern.

Each pattern is stamped with a frame-ID patch (see :mod:`frame_id`) so captured images can be
matched to what was shown. Works headless with ``QT_QPA_PLATFORM=offscreen`` for tests.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import cv2
import numpy as np
from pyqtgraph.Qt import QtCore, QtGui, QtWidgets

from vbfe.common.errors import DeviceError
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.projector.frame_id import N_BITS, stamp_frame_id
from vbfe.drivers.qt_app import qt_application

log = logging.getLogger(__name__)


class HdmiProjector(Projector):
    """Full-screen window on Qt screen ``screen`` (0 = primary); patterns are scaled to it.

    ``frame_id`` of each event is its sequence number modulo ``2**16``, stamped top-left in
    cells of ``cell_px`` pixels unless ``stamp`` is false.
    """

    def __init__(
        self,
        screen: int = 1,
        stamp: bool = True,
        cell_px: int = 8,
        host_clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        super().__init__(host_clock)
        self.screen, self.stamp, self.cell_px = int(screen), stamp, int(cell_px)
        self.width = self.height = 0
        self._app: QtWidgets.QApplication | None = None
        self._window: QtWidgets.QLabel | None = None

    @property
    def label(self) -> str:
        """The projector and its screen."""
        return f"projector screen {self.screen}"

    def _open(self) -> None:
        """Create the full-screen window on the chosen screen."""
        self._app = qt_application()
        screens = QtGui.QGuiApplication.screens()
        if not 0 <= self.screen < len(screens):
            names = [
                f"{i}: {s.name()} {s.geometry().width()}x{s.geometry().height()}"
                for i, s in enumerate(screens)
            ]
            raise DeviceError(
                f"projector screen {self.screen} does not exist; screens: {names}; "
                "connect the projector's HDMI cable or set the projector option "
                "'screen'"
            )
        geometry = screens[self.screen].geometry()
        self.width, self.height = geometry.width(), geometry.height()
        window = QtWidgets.QLabel()
        window.setWindowFlags(
            QtCore.Qt.WindowType.FramelessWindowHint | QtCore.Qt.WindowType.WindowStaysOnTopHint
        )
        window.setStyleSheet("background-color: black;")
        window.setAlignment(QtCore.Qt.AlignmentFlag.AlignLeft | QtCore.Qt.AlignmentFlag.AlignTop)
        window.setGeometry(geometry)
        window.showFullScreen()
        self._window = window
        self._app.processEvents()

    def _close(self) -> None:
        """Close the window."""
        if self._window is not None:
            self._window.close()
            self._window.deleteLater()
            self._window = None
            if self._app is not None:
                self._app.processEvents()

    def _show(self, pattern: np.ndarray, name: str, seq: int) -> int:
        """Show ``pattern`` (BGR ``uint8``) full-screen, stamped with frame ID ``seq % 2**16``."""
        app, window = self._screen()
        image: np.ndarray = np.ascontiguousarray(pattern, dtype=np.uint8)
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        if image.shape[:2] != (self.height, self.width):
            log.debug(
                "pattern %s is %dx%d, scaled to screen %dx%d",
                name,
                image.shape[1],
                image.shape[0],
                self.width,
                self.height,
            )
            image = cv2.resize(image, (self.width, self.height), interpolation=cv2.INTER_NEAREST)
        frame_id = seq % (1 << N_BITS)
        if self.stamp:
            image = stamp_frame_id(image, frame_id, self.cell_px)
        qimage = QtGui.QImage(
            image.data, self.width, self.height, image.strides[0], QtGui.QImage.Format.Format_BGR888
        )
        window.setPixmap(QtGui.QPixmap.fromImage(qimage))
        window.repaint()
        app.processEvents()
        return frame_id

    def _screen(self) -> tuple[QtWidgets.QApplication, QtWidgets.QLabel]:
        """The application and the full-screen window; DeviceError when closed."""
        if self._app is None or self._window is None:
            raise DeviceError(f"{self.label} is not open")
        return self._app, self._window

    def grab(self) -> np.ndarray:
        """What the window shows now, as a BGR image (for checks and tests)."""
        self.require_open()
        qimage = (
            self._screen()[1].grab().toImage().convertToFormat(QtGui.QImage.Format.Format_BGR888)
        )
        rows = np.frombuffer(qimage.constBits(), np.uint8).reshape(qimage.height(), -1)
        return rows[:, : qimage.width() * 3].reshape(qimage.height(), qimage.width(), 3).copy()

    def describe(self) -> dict[str, object]:
        """Static facts for session metadata: screen index and frame-ID stamp."""
        return {
            **super().describe(),
            "screen": self.screen,
            "frame_id_stamp": self.stamp,
            "frame_id_cell_px": self.cell_px,
            "frame_id_bits": N_BITS,
        }
