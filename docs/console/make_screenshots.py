"""Screenshots of the console's tabs for the README, on the simulated bench.

Rig, Live, Record and Review come from the headless command of docs/notes-console.md
(``vbfe console --record ... --duration 10 --screenshot-dir``); Calibrate and Sync show work
done: the window captures board views on the bench's board scene and calibrates, then runs the
sync protocol and applies its correction. Each PNG is scaled to ``WIDTH`` pixels.
Run: ``QT_QPA_PLATFORM=offscreen python docs/console/make_screenshots.py [TAB ...]`` (default:
every tab; e.g. ``Sync`` remakes that one).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pyqtgraph.Qt import QtCore

from vbfe.common.config import load_config
from vbfe.console.station import Station
from vbfe.console.window import ConsoleOptions, ConsoleWindow
from vbfe.drivers.qt_app import dispose_widget, qt_application
from vbfe.truth.scenes import board_config

HERE = Path(__file__).parent
WIDTH = 800


def save_small(path: Path) -> None:
    """Scale a screenshot down to ``WIDTH`` pixels, in place."""
    from pyqtgraph.Qt import QtGui

    image = QtGui.QImage(str(path))
    image.scaledToWidth(WIDTH, QtCore.Qt.TransformationMode.SmoothTransformation).save(str(path))


def run_until(window: ConsoleWindow, done, timeout_s: float) -> None:
    """Run the event loop until ``done()``."""
    app, end = qt_application(), time.monotonic() + timeout_s
    while not done():
        if time.monotonic() > end or window.errors:
            raise SystemExit(f"gave up: {window.errors}")
        app.processEvents()
        time.sleep(0.02)


def shoot(window: ConsoleWindow, name: str) -> None:
    window.tabs.setCurrentWidget(window.named_tabs()[name])
    window.refresh()
    qt_application().processEvents()
    path = HERE / f"{name.lower()}.png"
    window.grab().save(str(path))
    save_small(path)


def main() -> None:
    names = set(sys.argv[1:]) or {"Rig", "Live", "Record", "Calibrate", "Sync", "Review"}
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder)
        if names & {"Rig", "Live", "Record", "Review"}:
            recorded(out)
        if "Calibrate" in names:
            calibrate(out)
        if "Sync" in names:
            sync(out)


def recorded(out: Path) -> None:
    """Rig, Live, Record and Review from the headless command."""
    subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", "console", "--record", out / "c.h5"]
        + ["--duration", "10", "--screenshot-dir", out / "tabs", "--out", out],
        check=True,
    )
    for name in ("rig", "live", "record", "review"):
        (HERE / f"{name}.png").write_bytes((out / "tabs" / f"{name}.png").read_bytes())
        save_small(HERE / f"{name}.png")


def calibrate(out: Path) -> None:
    """Calibrate after a capture on the board scene and a calibration."""
    config = board_config(load_config())
    config["bench"].update(width=480, height=270)
    window = ConsoleWindow(Station(config), ConsoleOptions(out))
    window.show()
    tab = window.calibrate_tab
    window.tabs.setCurrentWidget(tab)
    tab.capture_button.setChecked(True)
    run_until(window, lambda: tab.capture is not None and tab.capture.kept >= 1, 300)
    run_until(window, lambda: not tab.capture_button.isChecked(), 300)
    tab.calibrate()
    run_until(window, lambda: tab.outcome is not None, 300)
    shoot(window, "Calibrate")  # the last view's corners, coverage, reasons, the result
    window.close()
    dispose_widget(window)


def sync(out: Path) -> None:
    """Sync after a protocol run and its correction."""
    config = load_config()
    config["bench"].update(width=160, height=90)
    window = ConsoleWindow(Station(config), ConsoleOptions(out))
    window.show()
    sync = window.sync_tab
    window.tabs.setCurrentWidget(sync)
    window.rig_op(window.station.go_live)
    sync.taps.setValue(10)
    sync.flashes.setValue(10)
    sync.duration.setValue(10.0)
    sync.run()
    run_until(window, lambda: sync.apply_button.isEnabled(), 300)
    sync.apply()
    run_until(window, lambda: sync.outcome is not None and sync.outcome.after is not None, 300)
    shoot(window, "Sync")
    window.close()
    dispose_widget(window)


if __name__ == "__main__":
    main()
