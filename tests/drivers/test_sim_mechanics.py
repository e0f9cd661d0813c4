"""Traction mechanics: the paper's protocol and a tissue model that is not a lookup table."""

import numpy as np
import pytest

from vbfe.common.errors import DeviceError
from vbfe.drivers.sim.mechanics import (
    HOLD,
    PAPER_CONDITIONS,
    PULL,
    REST,
    TissueSample,
    TractionProtocol,
    Trial,
)


@pytest.mark.parametrize("stiffness", sorted(PAPER_CONDITIONS))
def test_protocol_pulls_to_target_then_holds_it(stiffness):
    protocol = TractionProtocol(stiffness, PAPER_CONDITIONS[stiffness], target_force_n=3.0)
    t = np.linspace(0, protocol.duration_s(), 2000)
    u, force, phase = protocol.state(t)
    t_pull = protocol.pull_duration_s()
    # k·v = 0.4 N/s in all three conditions: elastic alone would take 7.5 s; viscosity shortens it
    assert 5.0 < t_pull < 7.5
    assert np.all(force[phase == REST] == 0) and np.all(u[phase == REST] == 0)
    pulling = phase == PULL
    assert np.all(np.diff(force[pulling]) > 0) and force[pulling].max() <= 3.0 + 1e-9
    assert np.allclose(np.diff(u[pulling]) / np.diff(t[pulling]), PAPER_CONDITIONS[stiffness])
    holding = phase == HOLD
    assert np.allclose(force[holding], 3.0)
    assert np.all(np.diff(u[holding]) > 0)  # creep at constant force …
    assert u[holding][-1] < 3.0 / stiffness  # … towards F/k


def test_state_is_continuous_at_the_switch_to_hold():
    protocol = TractionProtocol(80.0, 0.005)
    ts = protocol.rest_s + protocol.pull_duration_s()
    u, force, _ = protocol.state(np.array([ts - 1e-6, ts + 1e-6]))
    assert abs(u[1] - u[0]) < 1e-7 and abs(force[1] - force[0]) < 1e-3


def test_same_force_gives_different_shapes_across_stiffness():
    sample = TissueSample((0.0, 0.0), 0.003, (0.6, 0.0, -0.8))
    soft = Trial(TractionProtocol(40.0, 0.01), sample)
    hard = Trial(TractionProtocol(200.0, 0.002), sample)
    t_soft = soft.protocol.rest_s + soft.protocol.pull_duration_s()
    t_hard = hard.protocol.rest_s + hard.protocol.pull_duration_s()
    load_soft, f_soft, _ = soft.at(t_soft)
    load_hard, f_hard, _ = hard.at(t_hard)
    assert np.allclose(f_soft, f_hard)  # both at 3 N along the same direction
    assert np.linalg.norm(load_soft.vector_m) > 3 * np.linalg.norm(load_hard.vector_m)
    assert load_hard.radius_m > load_soft.radius_m


def test_force_vector_follows_the_pull_direction():
    rng = np.random.default_rng(4)
    sample = TissueSample.random(rng)
    assert abs(np.linalg.norm(sample.pull_direction) - 1) < 1e-12 and sample.pull_direction[2] < 0
    assert 0.002 <= sample.thickness_m <= 0.004
    trial = Trial(TractionProtocol(), sample)
    forces = trial.forces(np.array([0.0, 3.0, 9.0]))
    assert np.allclose(forces[0], 0)
    assert np.isclose(np.linalg.norm(forces[2]), 3.0)
    directions = forces[1:] / np.linalg.norm(forces[1:], axis=1, keepdims=True)
    assert np.allclose(directions, sample.pull_direction)


def test_folding_loads_are_refused():
    sample = TissueSample((0.0, 0.0), 0.002, (1.0, 0.0, 0.0))
    with pytest.raises(DeviceError, match="fold"):
        Trial(TractionProtocol(40.0, 0.01, target_force_n=8.0), sample)
