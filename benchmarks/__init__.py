"""The benchmarks (``python -m benchmarks.NAME``; each prints its own figures).

vbfe is imported before anything else of a benchmark: its thread-pool settings (passive OpenMP
waits, one OpenBLAS thread; ``vbfe/__init__.py``) take effect only when set before numpy and
torch load, as they are in ``vbfe`` commands. Loaded after torch, every small operation's
threads spin: a 2,000-step baseline fit took 62 s of CPU instead of 2 s at load 13.
"""

import vbfe  # noqa: F401
