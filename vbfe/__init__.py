"""vbfe: vision-based force estimation for soft-tissue interaction (structured light + stereo
endoscope)."""

import os

# Torch's OpenMP threads busy-wait between parallel regions by default: on a machine whose
# cores are busy with other work (a recording, a second program, CI beside other jobs) they
# spin against it, and a 20 s training took 270 s at load 20 (9 s of CPU became 100 s).
# Passive waiting sleeps instead; set before any vbfe module imports torch, and only when the
# user has not chosen (pytorch/pytorch#57715, #80777).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from vbfe.common.version import __version__  # noqa: E402

__all__ = ["__version__"]
