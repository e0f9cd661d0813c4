"""The simulated bench: stereo endoscope, projector, deforming tissue and trocar with ground
truth."""

from vbfe.drivers.sim.bench import SimBench

__all__ = ["SimBench"]
