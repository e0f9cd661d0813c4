"""Backend lookup, in the manner of python-can's interface table, and :func:`open_rig`.

A rig config names a ``backend`` per device family (``[camera]``, ``[trocar]``,
``[projector]``); the remaining keys of that table are the backend's constructor keyword
arguments, checked against its signature before anything is built. A backend listed in
:data:`SHARED` builds, once per rig, state its devices share (the simulator's bench), from the
whole rig config and the :class:`RigOptions`; its device factories take it as first argument.
Adding a device kind: a family in :data:`BACKENDS` (and its config table), or a backend in a
family; adding shared state: an entry in :data:`SHARED`.
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass
from typing import Any, Protocol

from vbfe.common.errors import DeviceError, VbfeError
from vbfe.common.settings import parse_kwargs
from vbfe.drivers.rig import Rig, RigOptions, SharedBackend
from vbfe.drivers.streams.opening import streams_from_config
from vbfe.drivers.streams.settings import stream_sources

BACKENDS: dict[str, dict[str, str]] = {
    "camera": {
        "v4l2": "vbfe.drivers.camera.linuxpy_v4l2:LinuxpyStereoCamera",
        "opencv": "vbfe.drivers.camera.opencv:OpenCVStereoCamera",
        "sim": "vbfe.drivers.sim.backend:camera",
    },
    "trocar": {
        "can": "vbfe.drivers.trocar.can_trocar:CanTrocar",
        "sim": "vbfe.drivers.sim.backend:trocar",
    },
    "projector": {
        "hdmi": "vbfe.drivers.projector.hdmi:HdmiProjector",
        "serial": "vbfe.drivers.projector.serial_projector:SerialProjector",
        "sim": "vbfe.drivers.sim.backend:projector",
    },
}
# backend -> factory(config, options) of the state its devices share within one rig
SHARED: dict[str, str] = {"sim": "vbfe.drivers.sim.backend:SimBackend"}
DEFAULT_BACKEND = "sim"
FAMILIES = tuple(BACKENDS)


class DeviceTables(Protocol):
    """What :func:`open_rig` reads of a rig configuration: its merged tables, checked
    (:class:`vbfe.rig_config.RigConfig` is one); the device tables are checked again against
    their backends here."""

    @property
    def tables(self) -> dict[str, dict[str, Any]]: ...


def _load(target: str) -> Any:
    module_name, name = target.split(":")
    return getattr(importlib.import_module(module_name), name)


def _factory(family: str, backend: str) -> Any:
    try:
        return _load(BACKENDS[family][backend])
    except KeyError:
        raise DeviceError(
            f"unknown {family} backend {backend!r}; known: {sorted(BACKENDS[family])}"
        ) from None


def device_options(family: str, table: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """``(backend, keyword arguments)`` of a device table, checked against the backend's
    constructor: an unknown key or a value of the wrong type is a ConfigError naming both."""
    options = dict(table)
    backend = options.pop("backend", DEFAULT_BACKEND)
    if not isinstance(backend, str):
        raise DeviceError(f"[{family}] backend must be a string, got {backend!r}")
    skip = ("shared",) if backend in SHARED else ()
    return backend, parse_kwargs(
        _factory(family, backend), options, family, where=f" (backend {backend})", skip=skip
    )


def open_rig(
    rig_config: DeviceTables,
    options: RigOptions = RigOptions(),
    families: tuple[str, ...] = FAMILIES,
) -> Rig:
    """The rig of ``families`` a rig configuration names, built but not opened (``with
    open_rig(...) as rig:`` opens every device, rolling back on failure, and closes them all).
    Every device table is checked against its backend before anything is built. The whole rig
    also has the ``[streams]`` (LSL streams, named by their keys), and then runs in real time:
    their samples come on the host's own clock."""
    config = rig_config.tables
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown:
        raise DeviceError(f"unknown device families {unknown}; known: {list(FAMILIES)}")
    streams = streams_from_config(config) if set(families) == set(FAMILIES) else {}
    if streams and options.realtime is None:
        options = dataclasses.replace(options, realtime=True)
    tables = {f: device_options(f, config.get(f, {})) for f in families}
    shared: dict[str, SharedBackend] = {
        b: _load(SHARED[b])(config, options) for b, _ in tables.values() if b in SHARED
    }
    devices = {}
    for family, (backend, kwargs) in tables.items():
        factory = _factory(family, backend)
        devices[family] = (
            factory(shared[backend], **kwargs) if backend in shared else factory(**kwargs)
        )
    rig = Rig(
        devices.get("camera"),
        devices.get("trocar"),
        devices.get("projector"),
        others={
            **{f: d for f, d in devices.items() if f not in ("camera", "trocar", "projector")},
            **streams,
        },
        shared=tuple(shared.values()),
    )
    # streams open first (resolving takes a second): a simulated bench's clock starts when its
    # first device opens, and its trocar would deliver that second as a backlog
    rig.devices = {**streams, **rig.devices}
    return rig


@dataclass(frozen=True)
class ConfiguredDevice:
    """A device the rig configuration names: ``name`` (a device family or a ``[streams]``
    key), its ``backend`` and its settings on one line (``key=value``)."""

    name: str
    backend: str
    settings: str


def configured_devices(rig_config: DeviceTables) -> list[ConfiguredDevice]:
    """The rig's devices as its configuration names them: camera, trocar, projector, then each
    ``[streams]`` entry (a bad table: ConfigError naming it)."""
    tables = rig_config.tables
    out = []
    for family in FAMILIES:
        options = dict(tables.get(family, {}))
        backend = str(options.pop("backend", DEFAULT_BACKEND))
        text = ", ".join(f"{k}={v}" for k, v in options.items())
        out.append(ConfiguredDevice(family, backend, text or "backend defaults"))
    for s in stream_sources(tables):
        required = "required" if s.required else "optional"
        out.append(ConfiguredDevice(s.key, s.backend, f"{s.predicate()} ({required})"))
    return out


def check_open(rig_config: DeviceTables, name: str) -> str | None:
    """Open and close the device ``name`` (a family or a ``[streams]`` key) on its own through
    its driver: ``None`` when it opens, else the one-line reason (a bad table included)."""
    try:
        if name in FAMILIES:
            rig = open_rig(rig_config, families=(name,))
        else:
            streams = streams_from_config(rig_config.tables)
            if name not in streams:
                raise DeviceError(f"the rig has no device {name!r}")
            rig = Rig(others={name: streams[name]})
    except VbfeError as exc:
        return " ".join(str(exc).split())
    # an optional stream that is not found opens, unread: its warning is the reason
    return rig.probe()[name] or getattr(rig.devices[name], "missing", None) or None
