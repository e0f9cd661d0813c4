"""Running the console: the window until it is closed (Ctrl-C and SIGTERM close it, which
finalizes a running recording), or headless for tests and documentation: record for a
duration, write screenshots of the tabs, exit."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from pyqtgraph.Qt import QtCore

from vbfe.acquire.viewer import exec_until_closed, grab_png
from vbfe.console.station import Finished, SessionRequest, Station
from vbfe.console.window import ConsoleOptions, ConsoleWindow
from vbfe.drivers.qt_app import dispose_widget, qt_application

RUNNING_TABS = ("Rig", "Live", "Record")  # shot while the recording runs: rates and numbers
_SHOT_AT = 0.8  # of the duration


@dataclass
class Headless:
    """What a headless run does: record for ``duration_s`` (or, without a recording, show the
    rig live that long), then ``screenshot`` (the Live tab) and ``screenshot_dir`` (one PNG
    per tab), then exit."""

    duration_s: float
    screenshot: Path | None = None
    screenshot_dir: Path | None = None


def grab_tab(window: ConsoleWindow, name: str, path: Path) -> Path:
    """The window showing tab ``name``, as a PNG."""
    window.tabs.setCurrentWidget(window.named_tabs()[name])
    qt_application().processEvents()
    window.refresh()
    return grab_png(window, path)


class HeadlessRun:
    """Drives a window through a headless run; ``code`` is the exit status (2: an error was
    shown in the window, printed to stderr too)."""

    def __init__(self, window: ConsoleWindow, plan: Headless, record: Path | None) -> None:
        self.window, self.plan, self.record = window, plan, record
        window.confirm_close = False  # nobody to ask: the run closes the window itself
        self.code = 0
        self.finished: Finished | None = None
        self.shot: set[str] = set()
        self._t0 = QtCore.QElapsedTimer()
        self._t0.start()
        window.finished_hooks.append(self._finished)
        self.timer = QtCore.QTimer(window)
        self.timer.timeout.connect(self.tick)
        self.timer.start(100)

    def _finished(self, finished: Finished) -> None:
        self.finished = finished

    def _shoot(self, names: tuple[str, ...]) -> None:
        plan = self.plan
        if plan.screenshot is not None and "Live" in names and "screenshot" not in self.shot:
            grab_tab(self.window, "Live", plan.screenshot)
            self.shot.add("screenshot")
        if plan.screenshot_dir is not None:
            plan.screenshot_dir.mkdir(parents=True, exist_ok=True)
            for name in names:
                if name not in self.shot:
                    grab_tab(self.window, name, plan.screenshot_dir / f"{name.lower()}.png")
                    self.shot.add(name)

    def tick(self) -> None:
        """Check for errors, take the screenshots when their time has come, close at the end."""
        window, plan = self.window, self.plan
        if window.errors:
            for error in window.errors:
                print(f"vbfe console: error: {error}", file=sys.stderr)
            self.code = 2
            self._close()
            return
        stats = window.station.stats()
        if stats is not None and stats.frames > 0 and stats.elapsed_s >= _SHOT_AT * plan.duration_s:
            self._shoot(RUNNING_TABS)
        live_done = self.record is None and self._t0.elapsed() / 1e3 >= plan.duration_s
        if (self.finished is not None or live_done) and not window.busy():
            self._shoot(tuple(window.named_tabs()))
            self._close()

    def _close(self) -> None:
        self.timer.stop()
        self.window.close()


def run_console(
    station: Station,
    options: ConsoleOptions,
    headless: Headless | None = None,
    record: Path | None = None,
    remote_port: int | None = None,
    remote_bind: str = "127.0.0.1",
) -> tuple[int, ConsoleWindow]:
    """Show the console over ``station`` until it closes, recording ``record`` at once when
    given; returns the exit status (0; 2 after an error in a headless run) and the (disposed)
    window's last state."""
    app = qt_application()
    window = ConsoleWindow(station, options)
    window.show()
    if remote_port is not None:
        window.record_tab.listen(remote_port, remote_bind)
    driver = HeadlessRun(window, headless, record) if headless is not None else None
    if record is not None:
        duration_s = headless.duration_s if headless is not None else None
        window.rig_op(
            station.start_recording,
            SessionRequest(record, duration_s=duration_s),
            what="cannot record",
        )
    else:
        window.rig_op(station.go_live, what="opening the rig")
    exec_until_closed(app, window, window.close_now)
    code = driver.code if driver is not None else 0
    dispose_widget(window)
    return code, window
