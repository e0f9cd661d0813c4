"""Review tab: the sessions in the data folder (date, duration, frames, drops, sync verdict,
markers, participant and task); the selected one's force with its markers, its ``vbfe report``
page (a link that opens in the browser) and its export to MCAP, each written off the UI
thread beside the session."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyqtgraph as pg
from pyqtgraph.Qt import QtWidgets

from vbfe.acquire.session.catalog import COLUMNS, SessionEntry, list_sessions
from vbfe.acquire.viewer import FORCE_PENS
from vbfe.batch.inputs import check_outputs
from vbfe.console.station import Finished
from vbfe.console.widgets import Tab, value_label, with_picker

if TYPE_CHECKING:
    from vbfe.console.window import ConsoleWindow

MARKER_PEN = "#800080"


def write_report(session: Path) -> Path:
    """``vbfe report SESSION.h5``: the page beside the session (an existing page is kept)."""
    from vbfe.session_report import write_session_report

    out = session.with_suffix(".html")
    if out.exists():
        return out
    return Path(write_session_report(session, out))


def export_session(session: Path) -> Path:
    """``vbfe export SESSION.h5``: ``SESSION.mcap`` beside it (an existing file is refused)."""
    from vbfe.bags.export import export_mcap

    out = session.with_suffix(".mcap")
    check_outputs([out], [session])
    return export_mcap(session, out).path


@dataclass(frozen=True)
class ForceView:
    """A session's force and markers on the report's time axis (seconds after the first
    frame)."""

    t_s: np.ndarray
    forces_n: np.ndarray
    axes: str
    marks: list[tuple[float, str]]


def force_view(session: Path) -> ForceView:
    """What the Review tab plots of ``session`` (as the report's force plot)."""
    from vbfe.acquire import SessionReader
    from vbfe.session_report import marker_times_s, plot_zero_host_ns, plot_zero_t0_ns

    with SessionReader(session) as r:
        t0 = plot_zero_t0_ns(r)
        forces, t = r.forces_n(), r.force_times_ns()
        marks = marker_times_s(r, plot_zero_host_ns(r, t0)) if len(t) else []
        return ForceView((t - t0) / 1e9, forces, "".join(r.force_axes), marks)


class ReviewTab(Tab):
    """The session browser over the selected session's force plot, report and export."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__(console)
        layout = QtWidgets.QVBoxLayout(self)
        top = QtWidgets.QHBoxLayout()
        self.folder = QtWidgets.QLineEdit(str(console.options.out_dir))
        top.addWidget(QtWidgets.QLabel("data folder"))
        top.addWidget(with_picker(self.folder, "folder", "data folder"), 1)
        self.refresh_button = QtWidgets.QPushButton("Refresh")
        self.refresh_button.clicked.connect(self.scan)
        top.addWidget(self.refresh_button)
        layout.addLayout(top)
        self.table = QtWidgets.QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionBehavior(QtWidgets.QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QtWidgets.QAbstractItemView.SelectionMode.SingleSelection)
        self.table.itemSelectionChanged.connect(self.selected)
        layout.addWidget(self.table, 2)
        self.plot = pg.PlotWidget(background="w")
        self.plot.setLabel("left", "force", units="N")
        self.plot.setLabel("bottom", "time since the first frame", units="s")
        self.plot.addLegend(offset=(5, 5))
        layout.addWidget(self.plot, 3)
        buttons = QtWidgets.QHBoxLayout()
        self.report_button = QtWidgets.QPushButton("Report page")
        self.report_button.clicked.connect(self.report)
        self.export_button = QtWidgets.QPushButton("Export to MCAP")
        self.export_button.clicked.connect(self.export)
        buttons.addWidget(self.report_button)
        buttons.addWidget(self.export_button)
        layout.addLayout(buttons)
        self.session = value_label()
        self.session.setText("no session selected")
        layout.addWidget(self.session)
        self.link = QtWidgets.QLabel()
        self.link.setOpenExternalLinks(True)
        layout.addWidget(self.link)
        self.entries: list[SessionEntry] = []
        self.shown: ForceView | None = None
        self.marker_lines: list[pg.InfiniteLine] = []
        self.page: Path | None = None
        self.scan()

    # -- the browser --------------------------------------------------------------------------
    def scan(self) -> None:
        """List the data folder's sessions (off the UI thread)."""
        folder = Path(self.folder.text().strip() or ".")
        if not folder.is_dir():
            self.console.message(f"{folder} is not a folder: choose the data folder", True)
            return
        self.console.work_op(list_sessions, folder, on_done=self.show_entries, what="sessions")

    def show_entries(self, entries: list[SessionEntry]) -> None:
        """Fill the table, newest first (the selection kept when it is still there)."""
        chosen = self.current()
        self.entries = entries
        self.table.setRowCount(len(entries))
        for r, entry in enumerate(entries):
            for c, text in enumerate(entry.row()):
                self.table.setItem(r, c, QtWidgets.QTableWidgetItem(text))
        self.table.resizeColumnsToContents()
        paths = [e.path for e in entries]
        if chosen is not None and chosen.path in paths:
            self.table.selectRow(paths.index(chosen.path))

    def current(self) -> SessionEntry | None:
        """The selected session."""
        rows = self.table.selectionModel().selectedRows()
        return self.entries[rows[0].row()] if rows and rows[0].row() < len(self.entries) else None

    def select(self, path: Path) -> None:
        """Select ``path`` in the table (when listed)."""
        for r, entry in enumerate(self.entries):
            if entry.path.resolve() == path.resolve():
                self.table.selectRow(r)

    def selected(self) -> None:
        """Plot the selected session's force and markers (read off the UI thread)."""
        entry = self.current()
        if entry is None:
            return
        row = zip(COLUMNS, entry.row(), strict=True)
        self.session.setText(" | ".join(f"{c}: {v}" for c, v in row))
        self.link.setText("")
        if entry.problem:
            return
        self.console.work_op(force_view, entry.path, on_done=self.show_force, what="review")

    def show_force(self, view: ForceView) -> None:
        """The force (each axis, |F|) with the markers as labelled lines."""
        self.plot.clear()
        self.marker_lines = []
        self.shown = view
        if len(view.t_s):
            for k, axis in enumerate(view.axes):
                pen = pg.mkPen(FORCE_PENS[k % 3], width=1)
                self.plot.plot(view.t_s, view.forces_n[:, k], pen=pen, name=f"F{axis}")
            magnitude = np.linalg.norm(view.forces_n, axis=1)
            self.plot.plot(view.t_s, magnitude, pen=pg.mkPen("k", width=2), name="|F|")
        for t, text in view.marks:
            line = pg.InfiniteLine(
                t,
                pen=pg.mkPen(MARKER_PEN, width=2, style=pg.QtCore.Qt.PenStyle.DashLine),
                label=text,
                labelOpts={"position": 0.9, "color": MARKER_PEN},
            )
            self.plot.addItem(line)
            self.marker_lines.append(line)

    # -- report and export --------------------------------------------------------------------
    def report(self) -> None:
        """Write (or find) the selected session's report page."""
        entry = self.current()
        if entry is None:
            self.console.message("select a session in the list first", True)
            return
        self.console.work_op(write_report, entry.path, on_done=self.show_page, what="report")

    def show_page(self, page: Path) -> None:
        """A link to the page (opens in the browser)."""
        self.page = page
        self.link.setText(f'report: <a href="{page.absolute().as_uri()}">{page}</a>')

    def export(self) -> None:
        """Export the selected session to MCAP beside it."""
        entry = self.current()
        if entry is None:
            self.console.message("select a session in the list first", True)
            return
        self.console.message(f"exporting {entry.path.name} to MCAP…")
        self.console.work_op(
            export_session,
            entry.path,
            on_done=lambda out: self.console.message(f"exported {out}"),
            what="export",
        )

    def on_finished(self, finished: Finished) -> None:
        """A new session: list it and select it."""
        folder = Path(self.folder.text().strip() or ".")
        if folder.is_dir():

            def listed(entries: list[SessionEntry]) -> None:
                self.show_entries(entries)
                self.select(finished.path)

            self.console.work_op(list_sessions, folder, on_done=listed, what="sessions")
