"""The simulated bench behind a configuration or a recorded session, where its truth is needed."""

from __future__ import annotations

from vbfe.acquire import SessionReader
from vbfe.common.errors import TruthError
from vbfe.drivers.sim import SimBench
from vbfe.drivers.sim.rig import StereoRig
from vbfe.rig_config import RigConfig


def true_rig(config: RigConfig) -> StereoRig:
    """The true rig of the bench a rig configuration's ``[bench]`` table describes."""
    return SimBench.from_config(config.tables["bench"]).rig


def trial_duration_s(config: RigConfig) -> float:
    """How long the trial of the configuration's bench lasts (no bench is built)."""
    return SimBench.duration_from_config(config.tables["bench"])


def session_bench(reader: SessionReader) -> SimBench:
    """The bench that recorded an open session, rebuilt from the description stored in it."""
    description = reader.metadata.get("bench")
    if description is None:
        raise TruthError(
            f"{reader.path} was not recorded on the simulated bench; it has no ground truth"
        )
    return SimBench.from_description(description)
