"""What hardware this machine has: V4L2 cameras, CAN interfaces and serial ports.

Everything is read from sysfs (``/sys/class/video4linux``, ``/sys/class/net``), the V4L2
nodes themselves through linuxpy (formats, frame sizes and rates, controls) and
``serial.tools.list_ports``; the roots and the linuxpy device factory are parameters so the
parsing can be checked against a made-up tree and a fake node.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from serial.tools import list_ports

from vbfe.drivers.camera.linuxpy_v4l2 import fourcc_name, linuxpy_device

ARPHRD_CAN = 280  # /sys/class/net/<if>/type of a CAN interface


@dataclass(frozen=True)
class VideoDevice:
    """One /dev/videoN node: its driver-given name, the pixel formats it offers, its modes
    (``MJPG 1920x1080 30/15 fps``) and controls (``gain = 32 (0..255 step 1, default 32)``)."""

    path: str
    name: str
    formats: tuple[str, ...]
    modes: tuple[str, ...] = ()
    controls: tuple[str, ...] = ()


@dataclass(frozen=True)
class CanInterface:
    """A network interface of type CAN (socketcan) and its state (up/down/unknown)."""

    name: str
    state: str


@dataclass(frozen=True)
class SerialPort:
    """A serial port and what the system says it is."""

    device: str
    description: str


@dataclass
class DeviceInventory:
    """Everything found, per device family."""

    cameras: list[VideoDevice] = field(default_factory=list)
    can_interfaces: list[CanInterface] = field(default_factory=list)
    serial_ports: list[SerialPort] = field(default_factory=list)


def _read(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return ""


def _natural_key(path: Path) -> tuple[str, int]:
    match = re.match(r"(\D*)(\d*)", path.name)
    assert match is not None  # the pattern matches any name
    return match[1], int(match[2] or -1)


def _rate(fps: Any) -> str:
    return f"{float(fps):g}"


def _modes(info: Any) -> tuple[str, ...]:
    """``FOURCC WxH rate/rate fps`` per frame size, from linuxpy's frame types."""
    rates: dict[tuple[str, int, int], list[str]] = {}
    for kind in info.frame_types:
        key = (fourcc_name(kind.pixel_format), int(kind.width), int(kind.height))
        rate = (
            _rate(kind.max_fps)
            if kind.min_fps == kind.max_fps
            else f"{_rate(kind.min_fps)}-{_rate(kind.max_fps)}"
        )
        rates.setdefault(key, []).append(rate)
    return tuple(f"{fmt} {w}x{h} {'/'.join(r)} fps" for (fmt, w, h), r in rates.items())


def _control(control: Any) -> str:
    try:
        value = control.value
    except (OSError, AttributeError, ValueError):
        value = "?"
    limits = f"{control.minimum}..{control.maximum} step {control.step}"
    default = getattr(control, "default", None)
    return f"{control.config_name} = {value} ({limits}" + (
        f", default {default})" if default is not None else ")"
    )


def probe_video_node(
    path: str, device_factory: Callable[[str], Any] = linuxpy_device
) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
    """Formats, modes and controls of a V4L2 node through linuxpy; empty when it cannot be
    opened or is not a capture node (metadata nodes)."""
    try:
        device = device_factory(path)
        device.open()
    except OSError:
        return (), (), ()
    try:
        formats = tuple(dict.fromkeys(fourcc_name(f.pixel_format) for f in device.info.formats))
        return (formats, _modes(device.info), tuple(_control(c) for c in device.controls.values()))
    except OSError:
        return (), (), ()
    finally:
        device.close()


def list_video_devices(
    sys_root: str | Path = "/sys",
    dev_root: str | Path = "/dev",
    device_factory: Callable[[str], Any] = linuxpy_device,
) -> list[VideoDevice]:
    """The V4L2 video nodes with their names, formats, modes and controls (metadata-only nodes
    included, with nothing to list)."""
    nodes = sorted((Path(sys_root) / "class" / "video4linux").glob("video*"), key=_natural_key)
    if not nodes:
        nodes = sorted(Path(dev_root).glob("video*"), key=_natural_key)
    found = []
    for node in nodes:
        path = str(Path(dev_root) / node.name)
        probe = probe_video_node(path, device_factory) if Path(path).exists() else ((), (), ())
        found.append(VideoDevice(path, _read(node / "name") or "?", *probe))
    return found


def list_can_interfaces(sys_root: str | Path = "/sys") -> list[CanInterface]:
    """Network interfaces whose type is CAN (socketcan: can0, vcan0, slcan0, ...)."""
    found = []
    for iface in sorted((Path(sys_root) / "class" / "net").glob("*"), key=_natural_key):
        if _read(iface / "type") == str(ARPHRD_CAN):
            found.append(CanInterface(iface.name, _read(iface / "operstate") or "unknown"))
    return found


def list_serial_ports() -> list[SerialPort]:
    """Serial ports pyserial can see (USB adapters, on-board UARTs)."""
    return [SerialPort(p.device, p.description or "") for p in sorted(list_ports.comports())]


def list_devices(
    sys_root: str | Path = "/sys",
    dev_root: str | Path = "/dev",
    on_step: Callable[[str], None] | None = None,
    device_factory: Callable[[str], Any] = linuxpy_device,
) -> DeviceInventory:
    """Cameras, CAN interfaces and serial ports; ``on_step(family)`` after each family."""
    inventory = DeviceInventory()
    steps: list[tuple[str, Callable[[], None]]] = [
        (
            "cameras",
            lambda: inventory.cameras.extend(
                list_video_devices(sys_root, dev_root, device_factory)
            ),
        ),
        ("CAN interfaces", lambda: inventory.can_interfaces.extend(list_can_interfaces(sys_root))),
        ("serial ports", lambda: inventory.serial_ports.extend(list_serial_ports())),
    ]
    for family, probe in steps:
        probe()
        if on_step is not None:
            on_step(family)
    return inventory


def format_inventory(inventory: DeviceInventory) -> str:
    """A plain-text report; says plainly when a family has no device."""
    lines = ["Cameras (V4L2):"]
    for cam in inventory.cameras:
        lines.append(f"  {cam.path}  {cam.name}  formats: {', '.join(cam.formats) or 'none'}")
        lines += [f"    mode     {mode}" for mode in cam.modes]
        lines += [f"    control  {control}" for control in cam.controls]
    if not inventory.cameras:
        lines.append("  none found (no /dev/video* device)")
    lines.append("CAN interfaces:")
    lines += [f"  {c.name}  {c.state}" for c in inventory.can_interfaces] or [
        "  none found (bring one up with: sudo ip link set can0 up type can bitrate 1000000)"
    ]
    lines.append("Serial ports:")
    lines += [f"  {p.device}  {p.description}" for p in inventory.serial_ports] or ["  none found"]
    return "\n".join(lines)
