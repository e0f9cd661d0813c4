"""The viewer draws images and the force curve (grabbed headless to PNG and checked)."""

from __future__ import annotations

import gc
import time

import cv2
import numpy as np

from tests.acquire.test_acquire_devices import bar_devices, write_bar_session
from vbfe.acquire import Acquisition, SessionReader
from vbfe.acquire.viewer import FORCE_PENS, LiveViewer, ReplayViewer, grab_png


def _has_colour(image: np.ndarray, hex_colour: str, min_pixels: int = 30) -> bool:
    rgb = np.array([int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)])
    close = np.abs(image[..., ::-1].astype(int) - rgb).sum(axis=2) < 40
    return int(close.sum()) >= min_pixels


def _plot_region(window, image):
    geo = window.plot.geometry()
    return image[geo.top() : geo.bottom(), geo.left() : geo.right()]


def test_replay_shows_frames_and_force_curve(tmp_path):
    path = tmp_path / "s.h5"
    write_bar_session(path, seconds=2.0, force_rate_hz=200.0)
    with SessionReader(path) as reader:
        window = ReplayViewer(reader)
        window.show()
        window.slider.setValue(reader.n_frames // 2)
        assert f"frame {reader.n_frames // 2}" in window.status.text()
        png = grab_png(window, tmp_path / "replay.png")
        image = cv2.imread(str(png))
        assert image.std() > 20
        plot = _plot_region(window, image)
        assert _has_colour(plot, FORCE_PENS[2])  # Fz curve drawn
        top = image[: window.plot.geometry().top()]
        assert (top > 150).mean() > 0.005  # the bright bar of the images is visible
        window.dispose()
        del window
        gc.collect()


def test_live_view_polls_an_acquisition_and_counts(tmp_path):
    acquisition = Acquisition(bar_devices(speed=50.0))
    window = LiveViewer(acquisition)
    acquisition.start()
    window.show()
    for _ in range(20):
        time.sleep(0.01)
        window.poll()
    assert "camera:" in window.status.text() and window.error is None
    image = cv2.imread(str(grab_png(window, tmp_path / "live.png")))
    assert image.std() > 20
    assert _has_colour(_plot_region(window, image), FORCE_PENS[2])
    window.dispose()
    del window
    gc.collect()
    acquisition.stop()
