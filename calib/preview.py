"""Live preview for ``calibrate capture``: the left image with detected corners and coverage bars.

Works headless with ``QT_QPA_PLATFORM=offscreen``.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from pyqtgraph.Qt import QtWidgets

from vbfe.calib.capture import Verdict, ViewCollector, annotate, coverage_text
from vbfe.drivers.qt_app import dispose_widget, qt_application


class CapturePreview(QtWidgets.QWidget):
    """A window showing each offered view, what happened to it and the coverage so far."""

    def __init__(self) -> None:
        self._app = qt_application()
        super().__init__()
        self.setWindowTitle("vbfe calibrate capture")
        self.resize(900, 600)
        layout = QtWidgets.QVBoxLayout(self)
        images = pg.GraphicsLayoutWidget()
        view = images.addViewBox(lockAspect=True, invertY=True, enableMouse=False)
        self.image = pg.ImageItem(axisOrder="row-major")
        view.addItem(self.image)
        layout.addWidget(images, stretch=1)
        self.status = QtWidgets.QLabel()
        layout.addWidget(self.status)
        self.show()

    def update_view(self, verdict: Verdict, collector: ViewCollector, left: np.ndarray) -> None:
        """Show one offered view (BGR) with its corners, the verdict and the coverage bars."""
        coverage = collector.coverage()
        if verdict.left is not None:
            left = annotate(left, verdict.left, coverage)
        self.image.setImage(
            np.ascontiguousarray(left[..., ::-1]), autoLevels=False, levels=(0, 255)
        )
        self.status.setText(f"{verdict.reason}\n{coverage_text(coverage, len(collector.pairs))}")
        self._app.processEvents()

    def dispose(self) -> None:
        """Close and delete the window now (see :func:`dispose_widget`)."""
        dispose_widget(self)
