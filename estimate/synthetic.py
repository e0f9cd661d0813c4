"""Synthetic pull-and-hold sessions as point clouds, for tests, benchmarks and dry runs.

A 30 mm square tissue patch 80 mm in front of the camera is pulled at ``pull_speed_m_per_s``:
the force ramps as ``k·v·t`` up to ``force_max_n`` and is then held. The surface under the
grasper rises towards the camera by ``lift_ratio × F/k`` as a Gaussian bump whose width grows
with stiffness (stiffer material spreads the deformation), so the cloud's shape carries the
force. Depth noise, dropped (NaN) pixels and a small per-session offset are added.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from vbfe.estimate.sources import SessionClouds

PAPER_CONDITIONS = ((40.0, 0.01), (80.0, 0.005), (200.0, 0.002))  # N/m, m/s


def pull_force_n(
    t_s: np.ndarray, stiffness_n_per_m: float, pull_speed_m_per_s: float, force_max_n: float = 3.0
) -> np.ndarray:
    """Force magnitude of a pull-then-hold at time ``t_s`` (ramp ``k·v·t`` capped at the max)."""
    return np.minimum(stiffness_n_per_m * pull_speed_m_per_s * np.maximum(t_s, 0), force_max_n)


def synthetic_session(
    name: str,
    stiffness_n_per_m: float,
    pull_speed_m_per_s: float,
    rng: np.random.Generator,
    fps: float = 30.0,
    hold_s: float = 2.0,
    force_max_n: float = 3.0,
    points_per_side: int = 40,
    lift_ratio: float = 0.1,
    noise_m: float = 1e-4,
    dropout: float = 0.05,
    offset_m: float = 3e-4,
) -> SessionClouds:
    """One simulated session (clouds in metres, trocar force in newtons at each frame)."""
    ramp_s = force_max_n / (stiffness_n_per_m * pull_speed_m_per_s)
    t_s = np.arange(0.0, ramp_s + hold_s, 1.0 / fps)
    magnitude = pull_force_n(t_s, stiffness_n_per_m, pull_speed_m_per_s, force_max_n)
    direction = np.array([0.2, 0.9, -0.4]) + rng.normal(0, 0.02, 3)
    forces = magnitude[:, None] * (direction / np.linalg.norm(direction))
    forces += rng.normal(0, 0.01, forces.shape)  # trocar noise, below its 0.1 N precision

    side = np.linspace(-0.015, 0.015, points_per_side)
    gx, gy = [g.ravel() for g in np.meshgrid(side, side)]
    offset = rng.normal(0, offset_m, 3)  # where the patch sits differs a little per session
    width_m = 0.004 * np.sqrt(stiffness_n_per_m / 40.0)
    bump = np.exp(-(gx**2 + gy**2) / (2 * width_m**2))
    clouds = []
    for f in magnitude:
        lift = lift_ratio * f / stiffness_n_per_m
        z = 0.08 - lift * bump + rng.normal(0, noise_m, gx.shape)
        points = np.column_stack([gx, gy, z]) + offset
        points[rng.random(len(points)) < dropout] = np.nan
        clouds.append(points)
    return SessionClouds(
        name=name,
        clouds=clouds,
        forces_n=forces,
        times_ns=np.round(t_s * 1e9).astype(np.int64),
        conditions={
            "stiffness_n_per_m": stiffness_n_per_m,
            "pull_speed_m_per_s": pull_speed_m_per_s,
        },
    )


def synthetic_sessions(
    conditions: Sequence[tuple[float, float]] = PAPER_CONDITIONS,
    repeats: int = 3,
    seed: int = 0,
    prefix: str = "sim",
    **options: Any,
) -> list[SessionClouds]:
    """``repeats`` sessions for each (stiffness N/m, pull speed m/s) condition."""
    rng = np.random.default_rng(seed)
    return [
        synthetic_session(f"{prefix}-k{k:g}-v{v:g}-r{r}", k, v, rng, **options)
        for k, v in conditions
        for r in range(repeats)
    ]
