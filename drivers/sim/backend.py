"""The simulator as an ordinary backend (``backend = "sim"``, like python-can's ``virtual``).

The devices of one rig share one :class:`SimBench`, built from the rig config's ``[bench]``
table and the command's :class:`~vbfe.drivers.rig.RigOptions` (real time, seed, the simulated
operator's taps); this is the only place that reads or changes that table for a rig.
"""

from __future__ import annotations

from typing import Any

from vbfe.drivers.rig import RigOptions
from vbfe.drivers.sim.bench import SimBench
from vbfe.drivers.sim.devices import SimCamera, SimProjector, SimTrocar


class SimBackend:
    """The bench the simulated devices of one rig share; its truth is the rig's."""

    def __init__(self, config: dict[str, dict[str, Any]], options: RigOptions) -> None:
        table = dict(config.get("bench", {}))
        if options.realtime is not None:
            table["realtime"] = options.realtime
        if options.seed is not None:
            table["seed"] = int(options.seed)
        if options.taps is not None:
            table.update(
                protocol="sync",
                sync_taps=options.taps.taps,
                sync_duration_s=options.taps.duration_s,
            )
        self.bench = SimBench.from_config(table)
        self.truth = self.bench

    def host_now_ns(self) -> int:
        """Now on the bench's host clock (simulated when not in real time)."""
        return self.bench.host_now_ns()

    def describe(self) -> dict[str, Any]:
        """The trial's conditions and the bench's description (enough to rebuild it)."""
        return {"conditions": self.bench.conditions(), "bench": self.bench.describe()}


def camera(shared: SimBackend, **options: Any) -> SimCamera:
    """The simulated stereo endoscope."""
    return shared.bench.camera(**options)


def trocar(shared: SimBackend, **options: Any) -> SimTrocar:
    """The simulated force trocar."""
    return shared.bench.trocar(**options)


def projector(shared: SimBackend, **options: Any) -> SimProjector:
    """The simulated projector."""
    return shared.bench.projector(**options)
