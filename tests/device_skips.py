"""Sync verdicts on the simulated bench when a busy machine starves it: the camera renders in
real time and skips frames it cannot render in time (a device-side drop, as a real camera's)."""

from __future__ import annotations

from collections.abc import Sequence

from vbfe.acquire.sync.check import DEVICE_SKIPPED

DEVICE_SKIPS = f"{DEVICE_SKIPPED}, 0 lost by the recorder"


def device_skips_only(reasons: Sequence[str]) -> bool:
    """Whether every reason of a FAIL is camera frames the device never delivered, the
    recorder itself having lost none, or the offset's interval they widened (a tap whose
    frames were skipped is fitted on fewer: 7.7 ms half-width with 43 % skipped, load 4.5)."""
    skipped = [r for r in reasons if r.startswith("camera dropped ") and r.endswith(DEVICE_SKIPS)]
    return bool(skipped) and all(
        r in skipped or r.startswith("offset uncertain: ") for r in reasons
    )
