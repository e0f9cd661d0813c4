"""`vbfe console` clicked through with pytest-qt on the simulated bench, and run headless
through the CLI: record with markers and remote control, bad inputs as messages in the window,
calibrate from captured board views, screenshots (the sync protocol and the rest of the day:
tests/app/test_console_day.py)."""

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from pyqtgraph.Qt import QtCore

from tests.paths import DATA
from vbfe.acquire import SessionReader
from vbfe.acquire.recording.remote import send_command
from vbfe.calib.report import gate_lines
from vbfe.console import TAB_NAMES
from vbfe.console.station import Station
from vbfe.console.window import ConsoleOptions, ConsoleWindow
from vbfe.drivers.qt_app import dispose_widget
from vbfe.rig_config import RigConfig, builtin_rig
from vbfe.truth import true_rig
from vbfe.truth.scenes import board_config

SAMPLE = DATA / "opencv_stereo"  # OpenCV's stereo sample (BSD)
CALIB_F_LIMIT, CALIB_B_LIMIT = 0.005, 0.01  # the demo's (vbfe/demo_report.py)
WAIT_MS = 60_000  # generous: the machine may be shared; passing runs take seconds


def bench_config(**bench) -> RigConfig:
    return builtin_rig({"bench": {"width": 192, "height": 108, "fps": 30.0, **bench}})


@pytest.fixture
def open_console(qtbot, tmp_path):
    """``open_console(config)``: a console window over the config's rig, live; closed (the
    recording finalized) at the end of the test."""
    windows = []

    def make(config: RigConfig, live: bool = True) -> ConsoleWindow:
        window = ConsoleWindow(Station(config), ConsoleOptions(tmp_path), interval_ms=50)
        window.show()
        windows.append(window)
        if live:
            window.rig_op(window.station.go_live, what="opening the rig")
            qtbot.waitUntil(lambda: window.station.latest.frame is not None, timeout=WAIT_MS)
        return window

    yield make
    for window in windows:
        window.close_now()
        dispose_widget(window)


def recorded_frames(window: ConsoleWindow) -> int:
    """Frames of the running recording so far (0 while none runs)."""
    stats = window.station.stats()
    return stats.frames if window.station.recording is not None and stats is not None else 0


def click(qtbot, button) -> None:
    qtbot.mouseClick(button, QtCore.Qt.MouseButton.LeftButton)


def test_record_with_markers_and_remote_control_then_refuse_an_existing_file(
    qtbot, open_console, tmp_path
):
    window = open_console(bench_config())
    tab = window.record_tab
    window.tabs.setCurrentWidget(tab)
    tab.root.setText(str(tmp_path))
    tab.operator.setText("operator A")
    tab.participant.setText("P007")
    tab.conditions.setText("stiffness=80, tissue=hose")
    first = tmp_path / "P007_traction_run-001.h5"
    assert tab.next_file.text() == "" or Path(tab.next_file.text()) == first
    click(qtbot, tab.start_button)
    qtbot.waitUntil(lambda: recorded_frames(window) >= 10 or bool(window.errors), timeout=WAIT_MS)
    assert not window.errors
    qtbot.keyClick(window, QtCore.Qt.Key.Key_M)
    click(qtbot, tab.mark_button)
    qtbot.waitUntil(lambda: "MB/s" in tab.numbers.text() and "markers 2" in tab.numbers.text())
    streams = {  # the streams a recording holds, from the rig configuration, counting
        tab.streams.item(r, 0).text(): tab.streams.item(r, 1).text()
        for r in range(tab.streams.rowCount())
    }
    assert list(streams) == ["camera", "force", "projector", "marks"]
    assert streams["marks"] == "2" and int(streams["force"]) > 0
    asked = []  # closing the window while recording asks first; "no" keeps it recording
    window.ask = lambda question: asked.append(question) or False
    window.close()
    assert asked == [f"Recording {first.name}: stop it and close the window?"]
    assert window.isVisible() and window.station.recording == first
    click(qtbot, tab.stop_button)
    tab.refresh()  # until the session is finalized: stopping, nothing to press
    assert tab.numbers.text().startswith("stopping: finalizing")
    assert not (tab.stop_button.isEnabled() or tab.start_button.isEnabled())
    qtbot.waitUntil(lambda: "last session" in tab.last.text(), timeout=WAIT_MS)
    with SessionReader(first) as reader:
        assert reader.complete
        assert [e["text"] for e in reader.events()] == ["marker 1", "marker 2"]
        meta = reader.metadata
        assert (meta["operator"], meta["participant"], meta["task"]) == (
            "operator A",
            "P007",
            "traction",
        )
        assert meta["rig"] == "simulated bench: no rig file (the built-in configuration)"
        conditions = reader.metadata["conditions"]  # the operator's, beside the bench's own
        assert (conditions["stiffness"], conditions["tissue"]) == (80.0, "hose")
    qtbot.waitUntil(lambda: tab.next_file.text().endswith("run-002.h5"))
    # remote control (vbfe record --remote's protocol) drives the console's recording
    qtbot.waitUntil(lambda: window.station.acquisition is not None, timeout=WAIT_MS)
    port = tab.listen(0)
    remote = tmp_path / "remote" / "R7_pull.h5"
    assert (
        send_command(
            f"filename {{root:{tmp_path / 'remote'}}} {{template:%p_%b.xdf}} "
            "{participant:R7} {task:pull}",
            port,
        )
        == "OK"
    )
    assert send_command("start", port) == "OK"
    qtbot.waitUntil(lambda: window.station.recording == remote, timeout=WAIT_MS)
    qtbot.waitUntil(lambda: recorded_frames(window) >= 5, timeout=WAIT_MS)
    assert send_command("mark trial start", port) == "OK"
    assert send_command("stop", port) == "OK"
    with SessionReader(remote) as reader:
        assert reader.complete and [e["text"] for e in reader.events()] == ["trial start"]
    # an existing file is refused in the window, and left as it was
    qtbot.waitUntil(lambda: window.station.acquisition is not None, timeout=WAIT_MS)
    tab.template.setText("fixed.h5")
    (tmp_path / "fixed.h5").write_bytes(b"an earlier session")
    click(qtbot, tab.start_button)
    qtbot.waitUntil(lambda: "already exists" in window.message_label.text())
    assert (tmp_path / "fixed.h5").read_bytes() == b"an earlier session"
    assert "choose a new file name" in window.errors[-1] and "--" not in window.errors[-1]
    # an empty template, a data folder two levels from any existing one: refused, nothing made
    tab.template.setText("")
    click(qtbot, tab.start_button)
    assert (
        window.errors[-1]
        == "cannot record: no file template: fill in 'file template', e.g. %p_%b_run-%n.h5"
    )
    tab.template.setText("%p.h5")
    tab.root.setText(str(tmp_path / "typo" / "data"))
    click(qtbot, tab.start_button)
    assert "choose an existing folder in 'folder'" in window.errors[-1]
    assert not (tmp_path / "typo").exists() and window.station.recording is None
    assert all("Traceback" not in e and "\n" not in e for e in window.errors)


def test_the_de_bruijn_overlay_colours_the_decoded_fringes(qtbot, open_console):
    window = open_console(bench_config(width=320, height=180))
    window.tabs.setCurrentWidget(window.live_tab)
    window.live_tab.overlay.setChecked(True)
    qtbot.waitUntil(lambda: window.live_tab.decoded is not None, timeout=WAIT_MS)
    left, overlay = window.live_tab.decoded
    assert overlay.shape == left.shape
    assert (overlay != left).any(axis=2).mean() > 0.5  # most of the tissue decodes


def test_the_live_tab_shows_the_estimate_of_a_loaded_model(qtbot, tmp_path):
    from vbfe.estimate.candidates import NetworkEstimator
    from vbfe.estimate.model_file import ForceModel
    from vbfe.estimate.pointnet import PointNetRegressor
    from vbfe.estimate.train_config import TrainConfig
    from vbfe.live.estimator import FrameEstimator
    from vbfe.truth import calibration_from_rig

    config = bench_config()
    train = TrainConfig(conv_channels=[8, 16, 32], head_channels=[16], n_points=128)
    network = PointNetRegressor(
        conv_channels=train.conv_channels,
        head_channels=train.head_channels,
        rest_depth=train.rest_depth,
    )
    model = ForceModel(
        config=train,
        selected="pointnet",
        estimators={"pointnet": NetworkEstimator(network.eval(), train.n_points)},
    )
    calibration = calibration_from_rig(true_rig(config))
    estimator = FrameEstimator(model, calibration, config.sgbm, scale=0.5)
    station = Station(config, calibration, estimator=estimator, model_name="untrained")
    window = ConsoleWindow(station, ConsoleOptions(tmp_path), interval_ms=50)
    window.show()
    window.tabs.setCurrentWidget(window.live_tab)
    try:
        window.rig_op(station.go_live)
        qtbot.waitUntil(
            lambda: station.live is not None and station.live.status().estimates >= 3,
            timeout=WAIT_MS,
        )
        qtbot.waitUntil(lambda: "latency p50" in window.live_tab.status.text(), timeout=WAIT_MS)
        curve = window.live_tab.estimate_curve  # drawn on the traces' turn, 10 times a second
        qtbot.waitUntil(lambda: curve.getData()[1] is not None, timeout=WAIT_MS)
        t_est, estimates = curve.getData()
        assert len(estimates) >= 1 and np.all(t_est <= 0) and np.all(np.isfinite(estimates))
    finally:
        window.close()
        dispose_widget(window)


def test_a_full_disk_and_a_missing_device_are_messages_in_the_window(qtbot, open_console, tmp_path):
    config = bench_config().updated({"record": {"min_free_gb": 1e9}})  # no disk has that room
    window = open_console(config)
    window.record_tab.root.setText(str(tmp_path))
    click(qtbot, window.record_tab.start_button)
    qtbot.waitUntil(lambda: "GB free" in window.message_label.text(), timeout=WAIT_MS)
    assert "free space or record elsewhere" in window.errors[-1]
    assert not list(tmp_path.glob("*.h5"))

    config = bench_config().updated({"camera": {"backend": "opencv", "device": "/dev/video99"}})
    window = open_console(config, live=False)
    click(qtbot, window.rig_tab.open_button)
    qtbot.waitUntil(lambda: bool(window.errors), timeout=WAIT_MS)
    assert window.errors[-1].startswith("opening the rig: cannot open camera /dev/video99")
    window.refresh()
    assert window.rig_tab.problem.text().startswith("camera: cannot open camera /dev/video99")
    states = {row[0]: row[2] for row in window.rig_tab.rows()}
    assert states["camera"].startswith("failed: cannot open camera")
    assert states["trocar"] == "closed"
    # each device of the rig configuration opened on its own through its driver
    rig_tab = window.rig_tab
    for name in ("camera", "trocar"):
        click(qtbot, rig_tab.test_buttons[name])
    qtbot.waitUntil(lambda: len(rig_tab.test_results) == 2, timeout=WAIT_MS)
    assert rig_tab.test_results["trocar"] == "OK: opens and closes"
    assert rig_tab.test_results["camera"].startswith("cannot open camera /dev/video99")
    assert "\n" not in rig_tab.test_results["camera"]
    results = {rig_tab.devices.item(r, 0).text(): rig_tab.devices.item(r, 4).text() for r in (0, 1)}
    assert results == rig_tab.test_results


def test_a_rig_file_with_a_typo_is_one_line_and_changes_nothing(qtbot, open_console, tmp_path):
    rig_file = tmp_path / "vbfe-rig.toml"
    rig_file.write_text("[bench]\nwidth = 192\nheight = 108\n[calib]\nsquares_xx = 9\n")
    before = rig_file.read_bytes()
    window = open_console(bench_config(), live=False)
    running = window.station.config
    window.rig_tab.rig_file.setText(str(rig_file))
    click(qtbot, window.rig_tab.open_file_button)
    assert len(window.errors) == 1 and "\n" not in window.errors[0]
    assert window.errors[0].startswith(f"rig file not opened: rig config {rig_file}")
    assert "squares_xx" in window.errors[0] and "Traceback" not in window.errors[0]
    assert window.station.config is running and window.options.rig_file is None
    # a rig file that gets a typo while the window keeps settled values in it: not written
    good = tmp_path / "good.toml"
    good.write_text("[bench]\nwidth = 192\nheight = 108\n")
    window.rig_tab.rig_file.setText(str(good))
    click(qtbot, window.rig_tab.open_file_button)
    assert window.options.rig_file == good and window.station.config.source.path == good
    good.write_text(before.decode())
    window.settled(correction_s=0.012)
    assert (
        window.errors[-1].startswith("rig file not updated:") and "squares_xx" in window.errors[-1]
    )
    assert good.read_bytes() == before and sorted(tmp_path.iterdir()) == [good, rig_file]


@pytest.mark.slow
def test_capture_board_views_and_calibrate_within_the_bench_truth(qtbot, open_console, tmp_path):
    # the minimum of views (the default 20 took 2 min on CI)
    config = board_config(bench_config(width=480, height=270)).updated(
        {"calib": {"capture_views": 8}}
    )
    window = open_console(config)
    tab = window.calibrate_tab
    window.tabs.setCurrentWidget(tab)
    (tmp_path / "endoscope.yaml").write_text("an earlier calibration")
    click(qtbot, tab.capture_button)
    qtbot.waitUntil(lambda: "board not seen" in tab.capture_text.text(), timeout=WAIT_MS)
    qtbot.waitUntil(
        lambda: not tab.capture_button.isChecked() or bool(window.errors), timeout=120_000
    )
    assert not window.errors
    kept = config.calib.capture_views  # as `calibrate capture`: enough views, full bars
    assert tab.capture.kept >= kept
    assert len(list((tmp_path / "calib-views").glob("*_left.png"))) == tab.capture.kept
    assert tab.capture.collector.coverage_map((480, 270)).sum() > 0
    click(qtbot, tab.calibrate_button)  # the calibration file exists: refused
    qtbot.waitUntil(lambda: "already exists" in window.message_label.text(), timeout=WAIT_MS)
    assert (tmp_path / "endoscope.yaml").read_text() == "an earlier calibration"
    tab.out.setText(str(tmp_path / "new.yaml"))
    click(qtbot, tab.calibrate_button)
    qtbot.waitUntil(lambda: tab.outcome is not None, timeout=120_000)
    calibration = tab.outcome.outcome.result.calibration
    truth = true_rig(config)
    assert abs(calibration.K1[0, 0] / truth.left.K[0, 0] - 1) < CALIB_F_LIMIT
    assert abs(calibration.B / truth.baseline_m - 1) < CALIB_B_LIMIT
    text = tab.result_text.text()  # the rows `vbfe calibrate stereo` prints, the gates
    assert "RMS left / right / stereo" in text and "per-view RMS" in text and "σ(B)" in text
    assert calibration.info["uncertainty"]["summary"] in text
    assert all(line in text for line in gate_lines(calibration))
    # the report's figures shown at their own size: per-view error etc. above the uncertainty
    figure = cv2.imread(str(tmp_path / "new.png"))
    uncertainty = cv2.imread(str(tmp_path / "new_uncertainty.png"))
    shown = tab.figures.pixmap()
    assert tab.pages.currentIndex() == 1
    assert (shown.width(), shown.height()) == (
        max(figure.shape[1], uncertainty.shape[1]),
        figure.shape[0] + uncertainty.shape[0],
    )
    assert (tmp_path / "new.yaml").is_file()


def test_a_board_that_is_not_found_is_a_message(qtbot, open_console, tmp_path):
    window = open_console(bench_config())  # the tissue scene: no board in view
    tab = window.calibrate_tab
    window.tabs.setCurrentWidget(tab)
    click(qtbot, tab.capture_button)
    qtbot.waitUntil(lambda: "board not seen" in tab.capture_text.text(), timeout=WAIT_MS)
    click(qtbot, tab.capture_button)
    click(qtbot, tab.calibrate_button)
    qtbot.waitUntil(lambda: bool(window.errors), timeout=WAIT_MS)
    assert window.errors[-1].startswith("calibration refused:")
    assert not (tmp_path / "endoscope.yaml").exists()


def test_click_a_refused_calibration_view_to_see_it_and_why(qtbot, open_console, tmp_path):
    """OpenCV's stereo sample (9x6 inner corners) and a pair without the board."""
    views = tmp_path / "views"
    views.mkdir()
    for k in range(1, 9):  # 8 of the sample's pairs: enough for a calibration, and quick
        for eye in ("left", "right"):
            shutil.copy(SAMPLE / f"{eye}{k:02d}.jpg", views)
    blank = np.full((480, 640, 3), 128, np.uint8)
    for eye in ("left", "right"):
        cv2.imwrite(str(views / f"{eye}15.jpg"), blank)
    window = open_console(bench_config(), live=False)
    tab = window.calibrate_tab
    window.tabs.setCurrentWidget(tab)
    tab.board.target.setCurrentText("chessboard")
    tab.board.squares_x.setValue(10)
    tab.board.squares_y.setValue(7)
    tab.folder.setText(str(views))
    tab.out.setText(str(tmp_path / "sample.yaml"))
    click(qtbot, tab.calibrate_button)
    qtbot.waitUntil(lambda: tab.outcome is not None or bool(window.errors), timeout=120_000)
    assert not window.errors
    rows = {tab.views.item(r, 0).text(): r for r in range(tab.views.rowCount())}
    assert len(rows) == 9
    status = {name: tab.views.item(r, 2).text() for name, r in rows.items()}
    refused = [name for name, text in status.items() if text != "used"]
    assert refused == ["15"] and status["15"].startswith("refused: too few corners (left 0")
    used_rms = [float(v) for v in tab.views.item(rows["01"], 1).text().split(" / ")]
    assert len(used_rms) == 3 and 0 < max(used_rms) < 1.0  # px; the sample's fit is sub-pixel
    tab.views.cellClicked.emit(rows["15"], 0)  # the refused view and why, on the view pane
    assert tab.pages.currentIndex() == 0
    assert tab.capture_text.text() == f"view 15: {status['15']}"
    shown = tab.view.items[0].image
    assert shown.shape[1] > 2 * shown.shape[0] and np.all(shown == 128)  # both eyes, no corners
    tab.views.cellClicked.emit(rows["01"], 0)  # a used view: its corners drawn in both eyes
    assert tab.capture_text.text().startswith("view 01: used; RMS left ")
    assert (tab.view.items[0].image != 128).any()
    window.refresh()  # the refresh keeps the view's line
    assert tab.capture_text.text().startswith("view 01: used")


def vbfe(*args, env=None, timeout=180):
    return subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )


def shows_both_images_and_the_force(png: Path) -> bool:
    """The Live tab's screenshot: the projected stripes in the left and right image panes,
    the force trace's pens in the plot below."""
    image = cv2.imread(str(png))
    h, w = image.shape[:2]
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    saturated = hsv[..., 1] > 120
    top = saturated[: h // 2]
    both = top[:, : w // 2].mean() > 0.05 and top[:, w // 2 :].mean() > 0.05
    plot = image[h // 2 :]
    pens = [(0x4B, 0x19, 0xE6), (0x4B, 0xB4, 0x3C), (0xD8, 0x63, 0x43)]  # FORCE_PENS, BGR
    traced = all((np.abs(plot.astype(int) - p).sum(axis=2) < 30).sum() > 200 for p in pens)
    return both and traced


def headless_console(tmp_path, env=None, duration=2):
    """The headless run of the issue on a small bench (the default rig's 640x360 is checked
    by hand and in benchmarks/bench_console.py)."""
    rig = tmp_path / "rig.toml"
    rig.write_text("[bench]\nwidth = 192\nheight = 108\n")
    return vbfe(
        "console",
        "--config",
        rig,
        "--record",
        tmp_path / "c.h5",
        "--duration",
        duration,
        "--screenshot",
        tmp_path / "c.png",
        "--screenshot-dir",
        tmp_path / "tabs",
        "--out",
        tmp_path,
        env=env,
    )


def test_headless_console_records_a_complete_session_and_screenshots_every_tab(tmp_path):
    result = headless_console(tmp_path)
    assert result.returncode == 0, result.stderr
    inspect = vbfe("inspect", tmp_path / "c.h5")
    status = [line for line in inspect.stdout.splitlines() if line.startswith(("status", "dur"))]
    assert "status    complete (duration reached)" in status, (status, result.stderr[-2000:])
    assert shows_both_images_and_the_force(tmp_path / "c.png")
    assert sorted(p.name for p in (tmp_path / "tabs").iterdir()) == sorted(
        f"{n.lower()}.png" for n in TAB_NAMES
    )
    again = headless_console(tmp_path)  # the session exists: refused, kept
    assert again.returncode == 2 and "Traceback" not in again.stderr
    assert again.stderr.strip().startswith("vbfe console: error:")
    assert "c.h5" in again.stderr


def test_headless_console_with_a_missing_device_exits_2_with_the_reason(tmp_path):
    (tmp_path / "rig.toml").write_text('[camera]\nbackend = "opencv"\ndevice = "/dev/video99"\n')
    result = vbfe("console", "--duration", 1, "--config", tmp_path / "rig.toml", "--out", tmp_path)
    assert result.returncode == 2
    assert "vbfe console: error: opening the rig: cannot open camera /dev/video99" in result.stderr
    assert "Traceback" not in result.stderr


def test_ctrl_c_closes_the_console_and_finalizes_the_recording(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text("[bench]\nwidth = 192\nheight = 108\n")
    session = tmp_path / "s.h5"
    process = subprocess.Popen(
        [sys.executable, "-m", "vbfe.cli.main", "console", "--record", session]
        + ["--config", rig, "--out", tmp_path],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (
        session.exists() and session.stat().st_size > 200_000
    ):
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    assert f"recorded {session}" in out
    with SessionReader(session) as reader:
        assert reader.complete and reader.n_frames > 0


@pytest.mark.skipif(
    shutil.which("Xvfb") is None, reason="Xvfb is not installed (apt-get install -y xvfb)"
)
def test_a_real_window_under_xvfb(tmp_path):
    read_end, write_end = os.pipe()  # Xvfb picks a free display and writes its number here
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write_end), "-screen", "0", "1280x800x24"],
        pass_fds=(write_end,),
        stderr=subprocess.DEVNULL,
    )
    os.close(write_end)
    try:
        with os.fdopen(read_end) as numbers:
            display = f":{numbers.readline().strip()}"
        env = {**os.environ, "DISPLAY": display, "QT_QPA_PLATFORM": "xcb"}
        result = headless_console(tmp_path, env=env, duration=2)
        assert result.returncode == 0, result.stderr
        assert shows_both_images_and_the_force(tmp_path / "c.png")
    finally:
        server.terminate()
        server.wait(timeout=10)


def test_a_recording_cut_off_by_kill_9_is_explained_by_the_next_window(
    qtbot, open_console, tmp_path
):
    from vbfe.common.files import WriterLock, stale_locks

    killed = subprocess.run(
        [
            sys.executable,
            "-c",
            "import os, signal; from vbfe.common.files import WriterLock; "
            f"WriterLock({str(tmp_path / 'cut.h5')!r}).acquire(); "
            "print(os.getpid(), flush=True); os.kill(os.getpid(), signal.SIGKILL)",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    pid = killed.stdout.strip()
    assert killed.returncode == -signal.SIGKILL and pid
    with WriterLock(tmp_path / "busy.h5"):  # held by a live writer: not stale
        assert stale_locks(tmp_path) == [(tmp_path / "cut.h5", pid)]
    window = open_console(bench_config(), live=False)
    tab = window.record_tab
    tab.root.setText(str(tmp_path))
    tab.check_stale()
    assert tab.stale.text().startswith(
        f"cut.h5 was not closed cleanly: its recorder (process {pid}) was killed"
    )
