"""Rig tab: every device of the rig with its state, rate, drops and clock offset, live; a
device that failed to open with the one-line reason."""

from __future__ import annotations

from typing import TYPE_CHECKING

from pyqtgraph.Qt import QtWidgets

from vbfe.console.widgets import Tab, value_label

if TYPE_CHECKING:
    from vbfe.console.window import ConsoleWindow

COLUMNS = ("device", "kind", "state", "rate", "records", "dropped", "clock offset")


class RigTab(Tab):
    """A table of the rig's devices and a button that (re)opens the rig live."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__(console)
        layout = QtWidgets.QVBoxLayout(self)
        self.table = QtWidgets.QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
        layout.addWidget(self.table, 1)
        self.problem = value_label()
        self.problem.setStyleSheet("color: #c00000")
        layout.addWidget(self.problem)
        self.open_button = QtWidgets.QPushButton("Open rig (live view)")
        self.open_button.clicked.connect(self.open_rig)
        layout.addWidget(self.open_button)

    def open_rig(self) -> None:
        """Start the live view (again)."""
        self.console.rig_op(self.station.go_live, what="opening the rig")

    def rows(self) -> list[tuple[str, ...]]:
        """One row of :data:`COLUMNS` per device."""
        rig, station = self.station.rig, self.station
        if rig is None:
            return []
        running = station.acquisition is not None
        out: list[tuple[str, ...]] = []
        for name, device in rig.devices.items():
            error = station.device_errors.get(name)
            stream = device.stream or ("projector" if name == "projector" else None)
            view = station.latest.view(stream) if stream and running else None
            stats = getattr(device, "stats", None)
            offset = view.clock_offset_s if view is not None else None
            state = (
                f"failed: {error}"
                if error
                else "open"
                if getattr(device, "is_open", False)
                else "closed"
            )
            out.append(
                (
                    name,
                    type(device).__name__,
                    state,
                    f"{view.rate_hz:.1f} /s" if view is not None else "-",
                    str(view.count) if view is not None else "-",
                    str(stats.dropped) if stats is not None else "-",
                    f"{offset:+.4f} s" if offset is not None else "-",
                )
            )
        return out

    def refresh(self) -> None:
        rows = self.rows()
        self.table.setRowCount(len(rows))
        for r, row in enumerate(rows):
            for c, text in enumerate(row):
                item = self.table.item(r, c)
                if item is None:
                    self.table.setItem(r, c, QtWidgets.QTableWidgetItem(text))
                elif item.text() != text:
                    item.setText(text)
        failed = {k: v for k, v in self.station.device_errors.items() if v}
        self.problem.setText("".join(f"{name}: {why}\n" for name, why in failed.items()).strip())
