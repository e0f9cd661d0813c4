"""A starting rig file for the devices this machine has (``vbfe rig init``).

The built-in rig (vbfe/default_rig.toml, every comment kept) with the device tables pointed at
what :func:`~vbfe.drivers.devices_list.list_devices` found: the first V4L2 camera, the first
CAN interface. What it cannot see (an HDMI projector, which serial port is which) stays on the
simulator, with a comment saying what to set.
"""

from __future__ import annotations

from importlib import resources

import tomlkit

from vbfe.drivers.devices_list import DeviceInventory


def starting_rig(inventory: DeviceInventory) -> tuple[str, list[str]]:
    """``(TOML text, one line per device table saying what was chosen)``."""
    text = resources.files("vbfe").joinpath("default_rig.toml").read_text(encoding="utf-8")
    doc = tomlkit.parse(text)
    notes = []
    camera, trocar = doc["camera"], doc["trocar"]
    if inventory.cameras:
        first = inventory.cameras[0]
        camera["backend"] = "v4l2"
        camera["device"] = first.path
        others = ", ".join(c.path for c in inventory.cameras[1:])
        notes.append(
            f"camera: v4l2 {first.path} ({first.name})"
            + (f"; also found {others} (a two-device endoscope: devices = [...])" if others else "")
        )
    else:
        notes.append("camera: none found, the simulated bench's")
    if inventory.can_interfaces:
        first_can = inventory.can_interfaces[0]
        trocar["backend"] = "can"
        trocar["interface"] = "socketcan"
        trocar["channel"] = first_can.name
        notes.append(f"trocar: can {first_can.name} ({first_can.state})")
    else:
        notes.append("trocar: no CAN interface found, the simulated bench's")
    ports = ", ".join(p.device for p in inventory.serial_ports)
    notes.append(
        "projector: the simulated bench's (an HDMI projector is not listed: set backend = "
        '"hdmi" and screen' + (f"; or serial, one of {ports})" if ports else ")")
    )
    header = (
        "# Rig file written by `vbfe rig init` from what `vbfe devices` found:\n"
        + "".join(f"#   {n}\n" for n in notes)
        + "# Commands find it as --config, $VBFE_RIG, ./vbfe-rig.toml or the user config folder.\n"
    )
    body = tomlkit.dumps(doc)
    body = body[body.index("[bench]") :]
    return header + "\n" + body, notes
