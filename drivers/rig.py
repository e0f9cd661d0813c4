"""A rig: the devices of one bench opened and closed together, with what their backends add.

``registry.open_rig(config)`` builds one from the rig config; tests and benchmarks may build one
from devices directly (``Rig(camera, trocar, projector)``). Devices a backend builds may share
state for the rig's lifetime (python-can's ``virtual`` bus shares its channels; the simulator
shares one bench): that state is a :class:`SharedBackend`, which adds its description
(e.g. the simulated trial's conditions) to :meth:`Rig.describe` and may know the truth.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from vbfe.common.closing import ClosedOnExit
from vbfe.common.errors import DeviceError
from vbfe.drivers.camera.base import StereoCamera
from vbfe.drivers.projector.base import Projector
from vbfe.drivers.trocar.base import ForceSensor


@dataclass(frozen=True)
class TapScript:
    """The operator taps the tissue ``taps`` times within ``duration_s`` (the sync protocol).
    A simulated operator plays it; a real one follows the printed instructions."""

    taps: int
    duration_s: float


@dataclass(frozen=True)
class RigOptions:
    """How a command wants the rig run; backends apply what they can (real devices ignore the
    simulator's). ``None`` keeps the rig config's value."""

    realtime: bool | None = None  # paced by the wall clock (a simulator may run faster)
    seed: int | None = None  # a simulated rig's random seed (e.g. the board's poses)
    taps: TapScript | None = None  # what a simulated operator does


class TruthSource(Protocol):
    """What a simulated rig knows about a recording (``None`` on hardware)."""

    def session_truth(self, frame_t_device_ns: np.ndarray) -> dict[str, np.ndarray]:
        """Per-frame truth for frames stamped ``frame_t_device_ns`` (camera clock)."""


class SharedBackend(Protocol):
    """State the devices of one backend share within a rig, built once per rig."""

    truth: TruthSource | None

    def describe(self) -> dict[str, Any]:
        """JSON-able facts merged into :meth:`Rig.describe` (keys other than ``devices``)."""


class Rig(ClosedOnExit):
    """Named devices opened and closed together (``with rig:`` or :meth:`open`/:meth:`close`).

    ``camera``, ``trocar`` and ``projector`` are the well-known ones; further kinds go in
    ``others``. Every device with a ``stream`` name (a
    :class:`~vbfe.drivers.device.SampleStream`) is read by an acquisition (see
    :class:`vbfe.acquire.Acquisition`). Usually built by
    :func:`vbfe.drivers.registry.open_rig` from a rig configuration.

    :param camera: the stereo endoscope, or ``None`` when the rig has none.
    :param trocar: the force sensor, or ``None``.
    :param projector: the structured-light projector, or ``None``.
    :param others: further devices by name (e.g. LSL streams).
    :param shared: state the devices of one backend share (the simulator's bench), whose
        facts :meth:`describe` adds and whose ground truth :attr:`truth` gives.
    """

    def __init__(
        self,
        camera: StereoCamera | None = None,
        trocar: ForceSensor | None = None,
        projector: Projector | None = None,
        *,
        others: Mapping[str, Any] | None = None,
        shared: tuple[SharedBackend, ...] = (),
    ) -> None:
        named = {"camera": camera, "trocar": trocar, "projector": projector, **(others or {})}
        self.devices: dict[str, Any] = {k: v for k, v in named.items() if v is not None}
        self.shared = shared

    @property
    def camera(self) -> StereoCamera:
        """The stereo camera.

        :raises DeviceError: the rig has none.
        """
        return self._get("camera")

    @property
    def trocar(self) -> ForceSensor:
        """The force sensor.

        :raises DeviceError: the rig has none.
        """
        return self._get("trocar")

    @property
    def projector(self) -> Projector:
        """The projector.

        :raises DeviceError: the rig has none.
        """
        return self._get("projector")

    def _get(self, name: str) -> Any:
        try:
            return self.devices[name]
        except KeyError:
            raise DeviceError(
                f"this rig has no {name}; add a [{name}] table to the rig config"
            ) from None

    def has(self, name: str) -> bool:
        """Whether the rig has a device called ``name``."""
        return name in self.devices

    def replace(self, name: str, device: Any) -> None:
        """Put ``device`` in the place of ``name`` (e.g. a test's wrapped camera)."""
        self.devices[name] = device

    @property
    def truth(self) -> TruthSource | None:
        """The ground truth of a simulated rig; ``None`` on hardware."""
        return next((s.truth for s in self.shared if s.truth is not None), None)

    def streams(self) -> Iterator[tuple[str, Any]]:
        """``(stream name, device)`` of the devices an acquisition reads."""
        for device in self.devices.values():
            if device.stream is not None:
                yield device.stream, device

    def describe(self) -> dict[str, Any]:
        """``{"devices": {name: device.describe()}}`` plus every shared backend's facts."""
        out: dict[str, Any] = {}
        for shared in self.shared:
            out.update(shared.describe())
        out["devices"] = {name: d.describe() for name, d in self.devices.items()}
        return out

    def host_now_ns(self) -> int:
        """Now on the host clock the devices stamp samples with (a simulator not run in real
        time keeps its own), e.g. for an event mark put in by the operator."""
        for backend in self.shared:
            clock = getattr(backend, "host_now_ns", None)
            if clock is not None:
                return int(clock())
        return time.monotonic_ns()

    def open(self) -> None:
        """Open every device (idempotent); if one fails, close those opened and re-raise.

        :raises DeviceError: a device is missing, busy or answers nonsense (the message names
            it).
        """
        opened = []
        try:
            for device in self.devices.values():
                device.open()
                opened.append(device)
        except BaseException:
            for device in reversed(opened):
                with contextlib.suppress(DeviceError):
                    device.close()
            raise

    def probe(self) -> dict[str, str | None]:
        """Open and close each device on its own: ``{name: None}`` when it opens, else the
        one-line reason it does not (the rig's devices are left closed)."""
        out: dict[str, str | None] = {}
        for name, device in self.devices.items():
            try:
                device.open()
            except DeviceError as exc:
                out[name] = " ".join(str(exc).split())
                continue
            with contextlib.suppress(DeviceError):
                device.close()
            out[name] = None
        return out

    def close(self) -> None:
        """Close every device (idempotent; a device already gone is not an error here)."""
        for device in reversed(list(self.devices.values())):
            with contextlib.suppress(DeviceError):
                device.close()

    def __enter__(self) -> Rig:
        self.open()
        return self
