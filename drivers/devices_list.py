"""What hardware this machine has: V4L2 cameras, CAN interfaces and serial ports.

Everything is read from sysfs (``/sys/class/video4linux``, ``/sys/class/net``), ``v4l2-ctl``
when installed (else an OpenCV probe) and ``serial.tools.list_ports``; the roots are parameters
so the parsing can be checked against a made-up tree.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
from serial.tools import list_ports

ARPHRD_CAN = 280  # /sys/class/net/<if>/type of a CAN interface


@dataclass(frozen=True)
class VideoDevice:
    """One /dev/videoN node: its driver-given name and the pixel formats it offers."""

    path: str
    name: str
    formats: tuple[str, ...]


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
    return match[1], int(match[2] or -1)


def video_formats(path: str) -> tuple[str, ...]:
    """FOURCCs a V4L2 device offers: from ``v4l2-ctl --list-formats``, else OpenCV's current one."""
    if not Path(path).exists():
        return ()
    if shutil.which("v4l2-ctl"):
        try:
            out = subprocess.run(["v4l2-ctl", "-d", path, "--list-formats"], capture_output=True,
                                 text=True, timeout=5).stdout
        except (subprocess.TimeoutExpired, OSError):
            return ()
        return tuple(dict.fromkeys(m.strip() for m in re.findall(r"'(\w{2,4}\s*)'", out)))
    cap = cv2.VideoCapture(path, cv2.CAP_V4L2)
    try:
        if not cap.isOpened():
            return ()
        code = int(cap.get(cv2.CAP_PROP_FOURCC))
        fourcc = "".join(chr((code >> 8 * i) & 0xFF) for i in range(4)).strip("\0 ")
        return (fourcc,) if fourcc else ()
    finally:
        cap.release()


def list_video_devices(sys_root: str | Path = "/sys",
                       dev_root: str | Path = "/dev") -> list[VideoDevice]:
    """The V4L2 video nodes with their names and formats (metadata-only nodes included)."""
    nodes = sorted((Path(sys_root) / "class" / "video4linux").glob("video*"), key=_natural_key)
    if not nodes:
        nodes = sorted(Path(dev_root).glob("video*"), key=_natural_key)
    found = []
    for node in nodes:
        path = str(Path(dev_root) / node.name)
        found.append(VideoDevice(path, _read(node / "name") or "?", video_formats(path)))
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


def list_devices(sys_root: str | Path = "/sys", dev_root: str | Path = "/dev",
                 on_step: Callable[[str], None] | None = None) -> DeviceInventory:
    """Cameras, CAN interfaces and serial ports; ``on_step(family)`` after each family."""
    inventory = DeviceInventory()
    steps: list[tuple[str, Callable[[], None]]] = [
        ("cameras", lambda: inventory.cameras.extend(list_video_devices(sys_root, dev_root))),
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
    lines += [f"  {c.path}  {c.name}  formats: {', '.join(c.formats) or 'unknown'}"
              for c in inventory.cameras] or ["  none found (no /dev/video* device)"]
    lines.append("CAN interfaces:")
    lines += [f"  {c.name}  {c.state}" for c in inventory.can_interfaces] or [
        "  none found (bring one up with: sudo ip link set can0 up type can bitrate 1000000)"]
    lines.append("Serial ports:")
    lines += [f"  {p.device}  {p.description}" for p in inventory.serial_ports] or [
        "  none found"]
    return "\n".join(lines)
