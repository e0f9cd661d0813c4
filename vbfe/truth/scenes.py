"""Rig configurations that put the simulated bench's calibration board in front of the endoscope."""

from __future__ import annotations

from typing import Any

from vbfe.rig_config import RigConfig

# The board moved by hand: a new pose every frame, some held still, some blurred.
HAND_HELD = {"scene": "board", "board_hold_s": 0.0}
# The board on a stand inside the projected area, moved every 6 s (longer than the 43 frames of
# a Gray-code pose at 10 fps), tilted more so that the projector's pose is well determined; an
# ideal projector (no latency, instant exposure), so every frame after a command shows it.
ON_A_STAND = {
    "scene": "board",
    "board_hold_s": 6.0,
    "board_in_projector": True,
    "board_max_tilt_deg": 45.0,
    "projector_latency_ms": 0.0,
    "exposure_ms": 0.0,
}


def board_config(config: RigConfig, on_a_stand: bool = False, **bench: Any) -> RigConfig:
    """``config`` with the bench showing the board (hand-held, or ``on_a_stand`` for projector
    calibration) and ``bench`` keys set. The simulated camera shows a new pattern from the next
    frame on, so the Gray-code capture needs no settle time there."""
    changes: dict[str, dict[str, Any]] = {
        "bench": {**(ON_A_STAND if on_a_stand else HAND_HELD), **bench}
    }
    if on_a_stand:
        changes["calib"] = {"projector_settle_s": 0.0}
    return config.updated(changes, "the board scene")
