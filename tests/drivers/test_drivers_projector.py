"""Projector drivers: the HDMI window (offscreen Qt) and the serial projector on a pty."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.fakes.serial_projector import FakeSerialProjector
from vbfe.common.errors import DeviceError
from vbfe.drivers.projector.frame_id import decode_frame_id, patch_size, stamp_frame_id
from vbfe.drivers.projector.hdmi import HdmiProjector
from vbfe.drivers.projector.serial_projector import SerialProjector


def stripes(width: int, height: int) -> np.ndarray:
    image = np.zeros((height, width, 3), np.uint8)
    image[:, ::16] = (0, 0, 255)
    image[:, 8::16] = (255, 0, 0)
    return image


@pytest.mark.parametrize("frame_id", [0, 1, 0x5A5A, 0xFFFF])
def test_frame_id_survives_scaling_blur_and_dim_projection(frame_id):
    stamped = stamp_frame_id(np.full((40, 200, 3), 90, np.uint8), frame_id, cell_px=8)
    w, h = patch_size(8)
    seen = cv2.resize(stamped[:h, :w], (w * 3 // 2, h * 3 // 2), interpolation=cv2.INTER_LINEAR)
    seen = cv2.GaussianBlur(seen, (3, 3), 0) * 0.5 + 30  # dim, offset, blurred
    assert decode_frame_id(seen.astype(np.uint8)) == frame_id


def test_frame_id_rejects_a_flipped_bit_and_flat_regions():
    stamped = stamp_frame_id(np.zeros((8, 160), np.uint8), 1234, cell_px=8)
    w, _ = patch_size(8)
    stamped[:, 5 * 8 : 6 * 8] ^= 255  # flip one data cell
    assert decode_frame_id(stamped[:, :w]) is None
    assert decode_frame_id(np.full((8, w), 128, np.uint8)) is None


def test_hdmi_window_shows_pattern_with_decodable_frame_ids():
    with HdmiProjector(screen=0) as projector:
        assert projector.width > 0 and projector.height > 0
        events = []
        for i in range(3):
            pattern = np.roll(stripes(320, 180), 4 * i, axis=1)
            events.append(projector.show(pattern, f"stripes{i}"))
            shown = projector.grab()
            assert shown.shape == (projector.height, projector.width, 3)
            w, h = patch_size(projector.cell_px)
            assert decode_frame_id(shown[:h, :w]) == events[-1].frame_id == i
            # away from the stamp the window shows the (scaled) pattern itself
            expected = cv2.resize(
                pattern, (projector.width, projector.height), interpolation=cv2.INTER_NEAREST
            )
            assert np.array_equal(shown[h:], expected[h:])
        with pytest.raises(DeviceError, match="screen 99 does not exist"):
            HdmiProjector(screen=99).open()
    assert [e.seq for e in events] == [0, 1, 2]
    assert events[0].t_host_ns < events[1].t_host_ns < events[2].t_host_ns


def test_serial_projector_talks_to_fake_on_a_pty():
    with FakeSerialProjector() as fake:
        with SerialProjector(port=fake.port, timeout_s=1.0) as projector:
            assert fake.power
            event = projector.show(np.zeros((4, 4, 3), np.uint8), "debruijn")
            assert fake.pattern == 1 and event.pattern == "debruijn" and event.frame_id == -1
            projector.command("brightness", percent=40)
            assert projector.command("status") == {"state": "ON", "index": "1", "percent": "40"}
            with pytest.raises(DeviceError, match="refused 'BRIGHTNESS 140'.*out of range"):
                projector.command("brightness", percent=140)
            with pytest.raises(DeviceError, match="no stored pattern 'checker'"):
                projector.show(np.zeros((4, 4, 3), np.uint8), "checker")
        assert not fake.power  # on_close powered it off
    assert fake.received[:2] == ["POWER ON", "PATTERN 1"]


def test_own_command_table_with_unstored_pattern_reports_device_error(tmp_path):
    table = tmp_path / "mine.toml"
    table.write_text(
        '[protocol]\nack = "^OK"\n[commands.pattern]\nsend = "PATTERN {index:d}"\n'
        "[patterns]\nfar = 7\n"
    )
    with FakeSerialProjector() as fake:
        with SerialProjector(port=fake.port, commands=table, timeout_s=1.0) as projector:
            with pytest.raises(DeviceError, match="no stored pattern 7"):
                projector.show(np.zeros((4, 4, 3), np.uint8), "far")
    assert fake.received == ["PATTERN 7"]  # no on_open/on_close in this table


def test_silent_projector_times_out_naming_the_port():
    with FakeSerialProjector(silent=True) as fake:
        with pytest.raises(DeviceError, match=f"projector on {fake.port} did not acknowledge"):
            SerialProjector(port=fake.port, timeout_s=0.2).open()


def test_missing_port_and_bad_table_are_device_errors(tmp_path):
    with pytest.raises(DeviceError, match="/dev/ttyVBFE-none.*dialout"):
        SerialProjector(port="/dev/ttyVBFE-none").open()
    bad = tmp_path / "bad.toml"
    bad.write_text("[commands.power_on]\nack = '^OK'\n")
    with pytest.raises(DeviceError, match="bad.toml is malformed"):
        SerialProjector(port="loop://", commands=bad)
