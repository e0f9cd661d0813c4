"""Small Qt pieces the console's tabs share: image panes and a labelled form."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pyqtgraph as pg
from pyqtgraph.Qt import QtCore, QtWidgets

if TYPE_CHECKING:
    from vbfe.console.station import Finished
    from vbfe.console.window import ConsoleWindow


MAX_SHOWN_WIDTH = 480


class ImagePane(pg.GraphicsLayoutWidget):
    """BGR images side by side, aspect kept, no mouse interaction."""

    def __init__(self, count: int = 1) -> None:
        super().__init__()
        self.items = []
        for _ in range(count):
            view = self.addViewBox(lockAspect=True, invertY=True, enableMouse=False)
            item = pg.ImageItem(axisOrder="row-major")
            view.addItem(item)
            self.items.append(item)

    def show_bgr(self, index: int, image: np.ndarray, max_width: int = MAX_SHOWN_WIDTH) -> None:
        """Show a BGR (or grey) uint8 image in pane ``index``, reduced to at most
        ``max_width`` pixels wide (painting a large image costs the UI thread)."""
        factor = -(-image.shape[1] // max_width)
        if factor > 1:
            size = (image.shape[1] // factor, image.shape[0] // factor)
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB) if image.ndim == 3 else image
        self.items[index].setImage(rgb, autoLevels=False, levels=(0, 255))


def with_picker(edit: QtWidgets.QLineEdit, kind: str, caption: str = "") -> QtWidgets.QWidget:
    """``edit`` with a "…" button beside it that picks a path into it: ``kind`` is "folder",
    "open" (an existing file) or "save" (a new file)."""
    button = QtWidgets.QToolButton()
    button.setText("…")
    button.setToolTip(f"choose {caption or kind}")

    def pick() -> None:
        start = edit.text().strip()
        dialogs = QtWidgets.QFileDialog
        if kind == "folder":
            chosen = dialogs.getExistingDirectory(edit, caption, start)
        elif kind == "open":
            chosen = dialogs.getOpenFileName(edit, caption, start)[0]
        else:
            chosen = dialogs.getSaveFileName(edit, caption, start)[0]
        if chosen:
            edit.setText(chosen)

    button.clicked.connect(pick)
    row = QtWidgets.QWidget()
    layout = QtWidgets.QHBoxLayout(row)
    layout.setContentsMargins(0, 0, 0, 0)
    layout.addWidget(edit, 1)
    layout.addWidget(button)
    return row


def form(rows: list[tuple[str, QtWidgets.QWidget]]) -> QtWidgets.QFormLayout:
    """A form layout of ``(label, widget)`` rows."""
    layout = QtWidgets.QFormLayout()
    for label, widget in rows:
        layout.addRow(label, widget)
    return layout


def value_label() -> QtWidgets.QLabel:
    """A label whose text can be selected (numbers, paths, reasons)."""
    label = QtWidgets.QLabel()
    label.setTextInteractionFlags(
        label.textInteractionFlags() | QtCore.Qt.TextInteractionFlag.TextSelectableByMouse
    )
    label.setWordWrap(True)
    label.setAlignment(QtCore.Qt.AlignmentFlag.AlignTop | QtCore.Qt.AlignmentFlag.AlignLeft)
    return label


def readonly_table(columns: Sequence[str]) -> QtWidgets.QTableWidget:
    """A table of ``columns`` the operator reads but does not edit, without row numbers."""
    table = QtWidgets.QTableWidget(0, len(columns))
    table.setHorizontalHeaderLabels(list(columns))
    table.horizontalHeader().setStretchLastSection(True)
    table.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
    table.verticalHeader().hide()
    return table


def show_rows(table: QtWidgets.QTableWidget, rows: Sequence[Sequence[str]]) -> None:
    """Show ``rows`` of texts in ``table``, touching only the cells whose text changed (a
    refresh tick does not repaint an unchanged table)."""
    table.setRowCount(len(rows))
    for r, row in enumerate(rows):
        for c, text in enumerate(row):
            item = table.item(r, c)
            if item is None:
                table.setItem(r, c, QtWidgets.QTableWidgetItem(text))
            elif item.text() != text:
                item.setText(text)


class Tab(QtWidgets.QWidget):
    """A console tab: a view over the console's station, redrawn by the window's timer."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__()
        self.console = console
        self.station = console.station

    def refresh(self) -> None:
        """Redraw from the station (every timer tick; keep it cheap)."""

    def on_finished(self, finished: Finished) -> None:
        """A recording ended."""
