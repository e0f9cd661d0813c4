"""Work that must give way: a thread that lowers its own scheduling priority.

The recorder's reader and writer threads keep the normal priority; beside a recording the live
estimate and the viewers lower theirs (:func:`yield_to_recording`), so that when the machine is
short of CPU the kernel runs the recording first and the estimate skips frames instead. On
Linux each thread has a nice value of its own (``setpriority`` on its thread id); threads it
starts afterwards (torch's worker pool among them) inherit it. Elsewhere nothing changes.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading

LIVE_NICE = 10  # a nice-10 thread gets about a tenth of the CPU a normal one gets beside it


def yield_to_recording(increment: int = LIVE_NICE) -> int | None:
    """Raise the calling thread's nice value by ``increment`` (Linux; an unprivileged process
    may always lower its priority). Returns the new nice value, ``None`` where threads have no
    priority of their own or it could not be set."""
    if sys.platform != "linux":
        return None
    tid = threading.get_native_id()
    with contextlib.suppress(OSError):
        nice = min(os.getpriority(os.PRIO_PROCESS, tid) + increment, 19)
        os.setpriority(os.PRIO_PROCESS, tid, nice)
        return nice
    return None
