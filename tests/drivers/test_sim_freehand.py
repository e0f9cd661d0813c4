"""The freehand protocol: a bench whose force cannot be read from the clock."""

import numpy as np
import pytest

from vbfe.common.errors import ConfigError, DeviceError
from vbfe.drivers.sim import SimBench
from vbfe.drivers.sim.freehand import RELEASE, FreehandProtocol
from vbfe.drivers.sim.mechanics import HOLD, PAPER_CONDITIONS, PULL, REST, TractionProtocol
from vbfe.rig_config import builtin_rig
from vbfe.truth import trial_duration_s

T = np.arange(0.0, 15.0, 0.01)


def freehand(seed, stiffness=80.0):
    return FreehandProtocol.random(np.random.default_rng(seed), stiffness, 15.0)


def test_one_trial_varies_speed_pauses_releases_and_holds_at_several_levels():
    protocol = freehand(3)
    u, force, phase = protocol.state(T)
    assert np.all(force[phase == REST] == 0) and force.max() <= 3.0 + 1e-6 and force.min() > -0.05
    # continuous: at most the fastest force rate (1.5 N/s, so 1.5/k m/s) over a 10 ms step
    assert np.abs(np.diff(force)).max() < 0.05 and np.abs(np.diff(u)).max() < 1.5 / 80 * 0.0101
    pulling = phase == PULL
    speed = np.diff(u)[pulling[1:] & pulling[:-1]] / 0.01
    assert np.percentile(speed, 90) > 3 * np.percentile(speed, 10) > 0  # the pull speed varies
    assert (phase == RELEASE).any()  # a partial release …
    first_release = np.flatnonzero(phase == RELEASE)[0]
    assert (phase[first_release:] == PULL).any()  # … and a pull again
    held = force[phase == HOLD]
    assert np.ptp(held) > 1.0  # holds at different force levels
    still = (phase[1:] == HOLD) & (phase[:-1] == HOLD) & (np.diff(u) == 0)
    # a still grasper (same shape) while the force relaxes after a pull, recovers after a release
    assert still.any() and (np.abs(np.diff(force)[still]) > 0).all()


def test_time_since_the_start_predicts_the_paper_protocol_but_not_the_freehand_one():
    """The timing shortcut: the mean force at each instant over training trials, scored on
    held-out trials, against the mean predictor."""

    def scores(trials):
        forces = np.array([p.state(T)[1] for p in trials])
        train, test = forces[:6], forces[6:]
        by_time = np.abs(test - train.mean(axis=0)).mean()
        return by_time / np.abs(test - train.mean()).mean()

    paper = [TractionProtocol(k, v) for k, v in PAPER_CONDITIONS.items()] * 3
    assert scores(paper) < 0.05
    rng = np.random.default_rng(0)
    hands = [
        freehand(seed, float(np.exp(rng.uniform(np.log(40), np.log(200))))) for seed in range(9)
    ]
    assert scores(hands) > 0.6


def test_trials_differ_in_stiffness_thickness_and_grasp():
    benches = [SimBench(seed=seed, protocol="freehand", width=64, height=36) for seed in range(4)]
    conditions = [b.conditions() for b in benches]
    stiffness = [c["stiffness_n_per_m"] for c in conditions]
    assert all(70 <= k <= 95 for k in stiffness) and max(stiffness) > 1.1 * min(stiffness)
    assert len({c["thickness_m"] for c in conditions}) == 4
    assert len({tuple(c["contact_m"]) for c in conditions}) == 4
    assert {c["protocol"] for c in conditions} == {"freehand"}
    for seed, bench in enumerate(benches):
        table = {"protocol": "freehand", "seed": seed}
        assert trial_duration_s(builtin_rig({"bench": table})) == bench.duration_s()
    again = SimBench.from_description(benches[1].describe())
    assert again.trial.protocol == benches[1].trial.protocol


@pytest.mark.parametrize(
    "table, error, message",
    [
        ({"protocol": "free-hand"}, ConfigError, "[bench] protocol = 'free-hand' is not one of"),
        (
            {"freehand_stifness_n_per_m": [40, 80]},
            ConfigError,
            "unknown key 'freehand_stifness_n_per_m' in [bench]",
        ),
        (
            {"protocol": "freehand", "freehand_stiffness_n_per_m": [95, 70]},
            DeviceError,
            "[bench] freehand protocol: freehand_stiffness_n_per_m",
        ),
    ],
)
def test_bad_bench_tables_are_one_line_errors(table, error, message):
    with pytest.raises(error) as raised:
        SimBench.from_config({**table, "width": 64, "height": 36})
    assert message in str(raised.value) and "\n" not in str(raised.value)
