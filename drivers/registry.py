"""Backend lookup, in the manner of python-can's interface table.

A rig config names a ``backend`` per device family; the remaining keys of that table are the
backend's constructor keyword arguments, checked against its signature before anything is
built. ``sim`` backends share one :class:`SimBench` so the camera sees what the projector shows
and what the trocar measures.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.errors import DeviceError
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.trocar.base import ForceSensor
from vbfe.settings import parse_kwargs

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


def device_options(family: str, table: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """``(backend, keyword arguments)`` of a device table, checked against the backend's
    constructor: an unknown key or a value of the wrong type is a ConfigError naming both."""
    options = dict(table)
    backend = options.pop("backend", "sim")
    if not isinstance(backend, str):
        raise DeviceError(f"[{family}] backend must be a string, got {backend!r}")
    if backend == "sim":
        from vbfe.drivers.sim import SimBench

        factory = getattr(SimBench, family)
    else:
        factory = _load(family, backend)
    return backend, parse_kwargs(factory, options, family, where=f" (backend {backend})")


def open_device(family: str, options: dict[str, Any], bench: Any | None = None) -> Any:
    """Construct (not open) one device from its config table; ``sim`` needs the shared bench."""
    backend, options = device_options(family, options)
    if backend == "sim":
        if bench is None:
            raise DeviceError(f"{family} backend 'sim' needs a simulated bench")
        return getattr(bench, family)(**options)
    return _load(family, backend)(**options)


def open_devices(config: dict[str, dict[str, Any]],
                 families: tuple[str, ...] = FAMILIES) -> Devices:
    """Construct the devices of ``families`` a rig config names (they still need opening); the
    others are ``None``. Simulated ones share one bench built from the ``[bench]`` table. Every
    device table is checked against its backend before anything is built."""
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown:
        raise DeviceError(f"unknown device families {unknown}; known: {list(FAMILIES)}")
    backends = {f: device_options(f, config[f])[0] for f in families}
    bench = None
    if "sim" in backends.values():
        from vbfe.drivers.sim import SimBench

        bench = SimBench.from_config(config.get("bench", {}))
    built = {f: open_device(f, config[f], bench) if f in families else None for f in FAMILIES}
    return Devices(**built, bench=bench)
