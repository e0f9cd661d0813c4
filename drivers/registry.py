"""Backend lookup, in the manner of python-can's interface table.

A rig config names a ``backend`` per device family; the remaining keys of that table are the
backend's constructor keyword arguments. ``sim`` backends share one :class:`SimBench` so the
camera sees what the projector shows and what the trocar measures.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.errors import DeviceError
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.trocar.base import ForceSensor

BACKENDS: dict[str, dict[str, str]] = {
    "camera": {"v4l2": "vbfe.drivers.camera.linuxpy_v4l2:LinuxpyStereoCamera",
               "opencv": "vbfe.drivers.camera.opencv:OpenCVStereoCamera"},
    "trocar": {"can": "vbfe.drivers.trocar.can_trocar:CanTrocar"},
    "projector": {
        "hdmi": "vbfe.drivers.projector.hdmi:HdmiProjector",
        "serial": "vbfe.drivers.projector.serial_projector:SerialProjector",
    },
}


FAMILIES = ("camera", "trocar", "projector")


@dataclass
class Devices:
    """The devices of a rig, plus the simulated bench when any of them is simulated."""

    camera: StereoCamera | None
    trocar: ForceSensor | None
    projector: Projector | None
    bench: Any | None = None  # vbfe.drivers.sim.SimBench


def _load(family: str, backend: str) -> type:
    try:
        target = BACKENDS[family][backend]
    except KeyError:
        known = sorted(BACKENDS[family]) + ["sim"]
        raise DeviceError(f"unknown {family} backend {backend!r}; known: {known}") from None
    module_name, class_name = target.split(":")
    return getattr(importlib.import_module(module_name), class_name)


def open_device(family: str, options: dict[str, Any], bench: Any | None = None) -> Any:
    """Construct (not open) one device from its config table; ``sim`` needs the shared bench."""
    options = dict(options)
    backend = options.pop("backend", "sim")
    if backend == "sim":
        if bench is None:
            raise DeviceError(f"{family} backend 'sim' needs a simulated bench")
        return getattr(bench, family)(**options)
    return _load(family, backend)(**options)


def open_devices(config: dict[str, dict[str, Any]],
                 families: tuple[str, ...] = FAMILIES) -> Devices:
    """Construct the devices of ``families`` a rig config names (they still need opening); the
    others are ``None``. Simulated ones share one bench built from the ``[bench]`` table."""
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown:
        raise DeviceError(f"unknown device families {unknown}; known: {list(FAMILIES)}")
    bench = None
    if any(config[f].get("backend", "sim") == "sim" for f in families):
        from vbfe.drivers.sim import SimBench

        bench = SimBench.from_config(config.get("bench", {}))
    built = {f: open_device(f, config[f], bench) if f in families else None for f in FAMILIES}
    return Devices(**built, bench=bench)
