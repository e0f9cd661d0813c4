"""Sync verdicts on the simulated bench when a busy machine starves it: the camera renders in
real time and skips frames it cannot render in time (a device-side drop, as a real camera's)."""

from __future__ import annotations

from collections.abc import Sequence


def device_skips_only(reasons: Sequence[str]) -> bool:
    """Whether every reason of a FAIL is camera frames the device never delivered, the
    recorder itself having lost none."""
    return bool(reasons) and all(
        r.startswith("camera dropped ")
        and r.endswith("never delivered by the device, 0 lost by the recorder")
        for r in reasons
    )
