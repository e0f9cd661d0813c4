"""Rig tab: the devices the rig configuration names, each with a "Test open" that opens it
through its driver and says OK or the one-line reason; every device of the running rig with
its state, rate, drops and clock offset, live; a device that failed to open with the one-line
reason; the simulated bench named as such; the rig file the window keeps what the operator
settles in (saved here as a new file)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from pyqtgraph.Qt import QtGui, QtWidgets

from vbfe.common.errors import VbfeError
from vbfe.common.files import error_line
from vbfe.console.desks import save_rig_file
from vbfe.console.widgets import Tab, readonly_table, show_rows, value_label, with_picker
from vbfe.drivers.registry import FAMILIES, configured_devices

if TYPE_CHECKING:
    from vbfe.console.window import ConsoleWindow

COLUMNS = ("device", "kind", "state", "rate", "records", "dropped", "clock offset")
CONFIGURED = ("device", "backend", "settings", "", "test result")
OPENS = "OK: opens and closes"


class RigTab(Tab):
    """A table of the rig's devices and a button that (re)opens the rig live."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__(console)
        layout = QtWidgets.QVBoxLayout(self)
        self.simulated = value_label()
        layout.addWidget(self.simulated)
        file_row = QtWidgets.QHBoxLayout()
        rig_file = console.options.rig_file
        self.rig_file = QtWidgets.QLineEdit(
            str(rig_file or console.options.out_dir / "vbfe-rig.toml")
        )
        file_row.addWidget(QtWidgets.QLabel("rig file"))
        file_row.addWidget(with_picker(self.rig_file, "save", "rig file"), 1)
        self.open_file_button = QtWidgets.QPushButton("Open rig file")
        self.open_file_button.clicked.connect(self.open_file)
        file_row.addWidget(self.open_file_button)
        self.save_button = QtWidgets.QPushButton("Save rig file")
        self.save_button.clicked.connect(self.save)
        file_row.addWidget(self.save_button)
        layout.addLayout(file_row)
        self.file_state = value_label()
        layout.addWidget(self.file_state)
        layout.addWidget(QtWidgets.QLabel("devices of the rig configuration"))
        self.devices = readonly_table(CONFIGURED)
        layout.addWidget(self.devices, 1)
        self.test_buttons: dict[str, QtWidgets.QPushButton] = {}
        self.test_results: dict[str, str] = {}  # device -> OPENS or why it does not open
        self._listed: object = None  # the device tables the list shows
        layout.addWidget(QtWidgets.QLabel("the running rig"))
        self.table = readonly_table(COLUMNS)
        layout.addWidget(self.table, 1)
        self.problem = value_label()
        self.problem.setStyleSheet("color: #c00000")
        layout.addWidget(self.problem)
        self.open_button = QtWidgets.QPushButton("Open rig (live view)")
        self.open_button.clicked.connect(self.open_rig)
        layout.addWidget(self.open_button)

    def open_file(self) -> None:
        """Run the rig the file in 'rig file' describes, and keep settled values there; a file
        that is missing or has a bad key is refused in one line naming it (nothing changes)."""
        path = Path(self.rig_file.text().strip())
        if self.station.recording is not None:
            self.console.message("stop the recording before opening another rig file", True)
            return
        try:
            self.console.use_rig_file(path)
        except VbfeError as exc:
            self.console.message(f"rig file not opened: {error_line(exc)}", True)
            return
        self.console.message(f"opened the rig file {path}; reopen the rig to run it")

    def save(self) -> None:
        """Write the rig as it runs now into a new rig file; settled values go there from now
        on."""
        path = Path(self.rig_file.text().strip())
        if path == self.console.options.rig_file:
            self.console.message(f"{path} is already the rig file: settled values go there")
            return
        try:
            save_rig_file(self.station.config, path)
        except (VbfeError, OSError) as exc:
            self.console.message(f"rig file not saved: {error_line(exc)}", True)
            return
        self.console.use_rig_file(path)
        self.console.message(f"saved the rig file {path}")

    def list_devices(self) -> None:
        """One row per device of the rig configuration, with its Test open button."""
        config = self.station.config
        self._listed = self._device_tables()
        try:
            devices = configured_devices(config)
        except VbfeError as exc:
            self.console.message(f"rig configuration: {error_line(exc)}", True)
            devices = []
        self.devices.setRowCount(len(devices))
        self.test_buttons, self.test_results = {}, {}
        for r, device in enumerate(devices):
            for c, text in enumerate((device.name, device.backend, device.settings)):
                self.devices.setItem(r, c, QtWidgets.QTableWidgetItem(text))
            button = QtWidgets.QPushButton("Test open")
            button.clicked.connect(lambda _=False, name=device.name: self.test_open(name))
            self.devices.setCellWidget(r, 3, button)
            self.devices.setItem(r, 4, QtWidgets.QTableWidgetItem("-"))
            self.test_buttons[device.name] = button
        self.devices.resizeColumnsToContents()

    def _device_tables(self) -> object:
        tables = self.station.config.tables
        return [tables.get(name) for name in (*FAMILIES, "streams")]

    def test_open(self, name: str) -> None:
        """Open and close ``name`` through its driver on the rig's thread; say OK or why not."""
        button = self.test_buttons[name]
        button.setEnabled(False)
        self._show_result(name, "opening…")

        def done(problem: str | None) -> None:
            button.setEnabled(True)
            self.test_results[name] = OPENS if problem is None else problem
            self._show_result(name, self.test_results[name])

        def failed() -> None:
            button.setEnabled(True)
            self._show_result(name, "not tested: see the message below")

        self.console.rig_op(
            self.station.test_open, name, on_done=done, what=f"test {name}", on_error=failed
        )

    def _show_result(self, name: str, text: str) -> None:
        row = list(self.test_buttons).index(name)
        item = QtWidgets.QTableWidgetItem(text)
        item.setToolTip(text)
        if text not in (OPENS, "opening…"):
            item.setForeground(QtGui.QColor("#c00000"))
        self.devices.setItem(row, 4, item)

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
        config = self.station.config
        if self._device_tables() != self._listed:
            self.list_devices()
        simulated = [
            name
            for name in ("camera", "trocar", "projector")
            if config.tables[name].get("backend") == "sim"
        ]
        self.simulated.setText(
            f"{config.banner()}\n"
            + (
                f"{', '.join(simulated)} simulated (set real backends in the rig file)"
                if simulated
                else "real devices"
            )
        )
        rig_file = self.console.options.rig_file
        self.file_state.setText(
            f"settled values (board, calibration, sync correction, model) are kept in {rig_file}"
            if rig_file is not None
            else "no rig file: settled values are lost when the window closes; save one here"
        )
        show_rows(self.table, self.rows())
        failed = {k: v for k, v in self.station.device_errors.items() if v}
        self.problem.setText("".join(f"{name}: {why}\n" for name, why in failed.items()).strip())
