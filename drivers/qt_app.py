"""The process's one Qt application and the safe disposal of Qt windows (viewer, previews, the
HDMI projector's window)."""

from __future__ import annotations

import gc

from pyqtgraph.Qt import QtWidgets


def qt_application() -> QtWidgets.QApplication:
    """The running ``QApplication``, created on first use (widgets need it first)."""
    return QtWidgets.QApplication.instance() or QtWidgets.QApplication([])


def dispose_widget(widget: QtWidgets.QWidget) -> None:
    """Close and delete ``widget`` now: PySide6 + pyqtgraph may crash when plot items are left
    for the interpreter's final garbage collection."""
    widget.close()
    widget.deleteLater()
    QtWidgets.QApplication.sendPostedEvents(None, 0)
    gc.collect()
