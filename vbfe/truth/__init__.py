"""Ground truth of the simulated bench, above the pipeline: for the demo, benchmarks and tests.

Nothing in ``drivers``' consumers (``acquire``, ``calib``, ``recon``, ``estimate``) imports this
package or ``vbfe.drivers.sim``; they see the bench only through the driver interfaces.
"""

from vbfe.common.errors import TruthError
from vbfe.truth.accuracy import AccuracyReport, evaluate_against_truth, rectified_truth
from vbfe.truth.bench import session_bench, trial_duration_s, true_rig
from vbfe.truth.calibration import calibration_from_rig
from vbfe.truth.scenes import board_config

__all__ = [
    "AccuracyReport",
    "TruthError",
    "board_config",
    "calibration_from_rig",
    "evaluate_against_truth",
    "rectified_truth",
    "session_bench",
    "trial_duration_s",
    "true_rig",
]
