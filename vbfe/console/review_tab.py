"""Review tab: the last session's ``vbfe report`` page, written off the UI thread after each
recording, as a link that opens in the browser."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from pyqtgraph.Qt import QtWidgets

from vbfe.console.station import Finished
from vbfe.console.widgets import Tab, value_label

if TYPE_CHECKING:
    from vbfe.console.window import ConsoleWindow


def write_report(session: Path) -> Path:
    """``vbfe report SESSION.h5``: the page beside the session (an existing page is kept)."""
    from vbfe.session_report import write_session_report

    out = session.with_suffix(".html")
    if out.exists():
        return out
    return Path(write_session_report(session, out))


class ReviewTab(Tab):
    """The last session and its report page."""

    def __init__(self, console: ConsoleWindow) -> None:
        super().__init__(console)
        layout = QtWidgets.QVBoxLayout(self)
        self.session = value_label()
        self.session.setText("no session recorded yet")
        layout.addWidget(self.session)
        self.link = QtWidgets.QLabel()
        self.link.setOpenExternalLinks(True)
        layout.addWidget(self.link)
        layout.addStretch(1)
        self.page: Path | None = None

    def on_finished(self, finished: Finished) -> None:
        self.session.setText(f"last session: {finished.line()}\nwriting its report…")
        self.console.work_op(write_report, finished.path, on_done=self.show_page, what="report")

    def show_page(self, page: Path) -> None:
        """A link to the page (opens in the browser)."""
        self.page = page
        self.session.setText(self.session.text().replace("\nwriting its report…", ""))
        self.link.setText(f'report: <a href="{page.absolute().as_uri()}">{page}</a>')
