"""`vbfe devices` and the hardware listing behind it."""

from __future__ import annotations

import json
import subprocess
import sys

from vbfe.cli.main import main
from vbfe.drivers.devices_list import (
    format_inventory,
    list_can_interfaces,
    list_devices,
    list_video_devices,
)


def make_sysfs(root):
    net = root / "class" / "net"
    for name, kind, state in [
        ("eth0", "1", "up"),
        ("can0", "280", "up"),
        ("vcan1", "280", "down"),
        ("lo", "772", "unknown"),
    ]:
        (net / name).mkdir(parents=True)
        (net / name / "type").write_text(kind + "\n")
        (net / name / "operstate").write_text(state + "\n")
    for name, label in [("video2", "Endoscope R"), ("video0", "Endoscope L"), ("video10", "Meta")]:
        (root / "class" / "video4linux" / name).mkdir(parents=True)
        (root / "class" / "video4linux" / name / "name").write_text(label + "\n")
    return root


def test_sysfs_parsing_finds_can_interfaces_and_cameras(tmp_path):
    sysfs = make_sysfs(tmp_path / "sys")
    cans = list_can_interfaces(sysfs)
    assert [(c.name, c.state) for c in cans] == [("can0", "up"), ("vcan1", "down")]
    cams = list_video_devices(sysfs, dev_root=tmp_path / "dev")
    assert [(c.path, c.name) for c in cams] == [
        (str(tmp_path / "dev" / "video0"), "Endoscope L"),
        (str(tmp_path / "dev" / "video2"), "Endoscope R"),
        (str(tmp_path / "dev" / "video10"), "Meta"),
    ]
    assert all(c.formats == () for c in cams)  # no device nodes to probe
    text = format_inventory(list_devices(sysfs, tmp_path / "dev"))
    assert "can0  up" in text and "Endoscope R" in text


def test_empty_machine_says_none_found(tmp_path):
    text = format_inventory(list_devices(tmp_path / "sys", tmp_path / "dev"))
    assert "Cameras (V4L2):\n  none found" in text
    assert "CAN interfaces:\n  none found" in text and "ip link set can0 up" in text


def test_devices_command_exits_0_in_process(capsys):
    assert main(["devices"]) == 0
    out = capsys.readouterr().out
    for family in ("Cameras (V4L2):", "CAN interfaces:", "Serial ports:"):
        assert family in out
    assert main(["devices", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert set(listed) == {"cameras", "can_interfaces", "serial_ports"}


def test_devices_command_exits_0_as_a_process():
    done = subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", "devices"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    inventory = list_devices()
    if not inventory.cameras:
        assert "none found (no /dev/video* device)" in done.stdout
    if not inventory.can_interfaces:
        assert "CAN interfaces:\n  none found" in done.stdout


def test_cameras_list_formats_sizes_rates_and_controls_through_linuxpy(tmp_path):
    from tests.fakes.v4l2 import FakeV4L2Node, fake_factories

    sysfs = make_sysfs(tmp_path / "sys")
    dev = tmp_path / "dev"
    dev.mkdir()
    (dev / "video0").touch()  # only this node exists: the others are not probed
    node = FakeV4L2Node(str(dev / "video0"), 64, 48)
    factory = fake_factories(node)["device_factory"]
    cams = list_video_devices(sysfs, dev, device_factory=factory)
    left = cams[0]
    assert left.formats == ("MJPG", "YUYV")
    assert left.modes == ("MJPG 64x48 30/15 fps", "YUYV 64x48 30/15 fps")
    assert "exposure_time_absolute = 156 (3..2047 step 1, default 156)" in left.controls
    assert node.closed and cams[1].formats == () and cams[1].controls == ()
    text = format_inventory(list_devices(sysfs, dev, device_factory=factory))
    assert "    mode     MJPG 64x48 30/15 fps" in text
    assert "    control  white_balance_automatic = 1 (0..1 step 1, default 1)" in text
