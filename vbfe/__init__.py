"""vbfe: vision-based force estimation for soft-tissue interaction (structured light + stereo
endoscope)."""

import os

# Thread pools that busy-wait starve the recorder's threads and each other on a machine whose
# cores are busy (a recording, a second program, CI beside other jobs). Set before numpy,
# scipy or torch load, and only where the user has not chosen:
# - torch's OpenMP threads wait passively between parallel regions: a 20 s MLP fit took 270 s
#   at load 20 when they spun (9 s of CPU became 100 s) (pytorch/pytorch#57715, #80777);
# - OpenBLAS (numpy, scipy) runs one thread: vbfe's linear algebra is many small solves (the
#   sync fits' SVDs of 3000x6 Jacobians), which a second thread only slows: a sync check took
#   76 s (25 s CPU) at load 16 with OpenBLAS's threads, 14 s (2.6 s CPU) on one.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from vbfe.common.version import __version__  # noqa: E402

__all__ = ["__version__"]
