"""Baselines: each recovers the relation it models from training data."""

import numpy as np

from vbfe.estimate.baselines import AffineBaseline, baseline_from_dict, fit_baselines
from vbfe.estimate.candidates import estimator_from_dict
from vbfe.estimate.dataset import PreparedSession
from vbfe.estimate.image_models import RidgeThumbnail, fit_ridge, fit_ridge_thumbnails


def prepared(name, displacement_m, force_n, condition):
    n = len(displacement_m)
    d = np.nan_to_num(np.asarray(displacement_m, float))
    return PreparedSession(
        name=name,
        conditions=condition,
        frame_index=np.arange(n),
        times_ns=np.arange(n, dtype=np.int64),
        targets_n=np.asarray(force_n, float).reshape(n, -1),
        pools=np.zeros((n, 4, 3), np.float32),
        displacement_m=np.asarray(displacement_m, float),
        texture_displacement_m=np.full(n, np.nan),
        image_sum=np.repeat(d[:, None, None], 4, 1).repeat(4, 2),
        image_count=np.ones((n, 4, 4), np.float32),
        n_frames_total=n,
        n_no_cloud=0,
        n_no_force=0,
    )


def all_frames(sessions):
    return [(s, np.arange(s.n_used)) for s in sessions]


def test_fitted_baselines_recover_known_relations():
    d = np.linspace(0, 0.01, 50)
    sessions = [
        prepared("a", d, 120.0 * d, {"stiffness_n_per_m": 40.0}),
        prepared("b", d, 120.0 * d, {"stiffness_n_per_m": 80.0}),
    ]
    sessions[1].displacement_m[3] = np.nan  # frames without displacement are left out
    fitted = fit_baselines(all_frames(sessions))
    assert set(fitted) == {"mean", "linear_displacement", "hooke"}
    np.testing.assert_allclose(fitted["hooke"].slope, [120.0], rtol=1e-9)
    np.testing.assert_allclose(fitted["hooke"].intercept, 0.0)
    np.testing.assert_allclose(fitted["linear_displacement"].slope, [120.0], rtol=1e-9)
    np.testing.assert_allclose(fitted["linear_displacement"].intercept, [0.0], atol=1e-9)
    np.testing.assert_allclose(
        fitted["mean"].predict(np.array([0.0, 1.0])),
        [[np.mean(np.concatenate([s.targets_n for s in sessions]))]] * 2,
    )


def test_linear_and_hooke_differ_when_force_has_an_offset():
    d = np.linspace(0.001, 0.01, 40)
    fitted = fit_baselines(all_frames([prepared("a", d, 1.0 + 100.0 * d, {})]))
    np.testing.assert_allclose(fitted["linear_displacement"].predict(np.array([0.02]))[0], [3.0])
    assert fitted["hooke"].intercept[0] == 0.0
    assert abs(fitted["hooke"].predict(np.array([0.02]))[0, 0] - 3.0) > 0.1


def test_baseline_round_trips_through_a_dict():
    b = AffineBaseline("hooke", np.array([1.0, 2.0, 3.0]), np.zeros(3))
    again = AffineBaseline.from_dict(b.to_dict())
    np.testing.assert_array_equal(
        again.predict(np.array([0.5, np.nan])), [[0.5, 1.0, 1.5], [0.0, 0.0, 0.0]]
    )


def test_ridge_picks_the_thumbnail_size_and_penalty_on_validation_and_round_trips():
    # force reads one 2×2 quadrant of a 4×4 image: a 2×2 thumbnail sees it whole, a 1×1
    # thumbnail mixes it with the noise of the other quadrants
    rng = np.random.default_rng(0)
    n = 400
    image = rng.normal(0, 1e-3, (n, 4, 4))
    force = 1e3 * image[:, :2, :2].sum(axis=(1, 2)) + 2.0
    session = prepared("r", np.zeros(n), force, {})
    session.image_sum, session.image_count = image, np.ones((n, 4, 4))
    train, val, test = np.arange(250), np.arange(270, 330), np.arange(350, 400)
    ridge = fit_ridge_thumbnails([(session, train)], [(session, val)], [1, 2, 4])
    assert ridge.size in (2, 4)
    predicted = ridge.predict_session(session, test)[:, 0]
    assert np.abs(predicted - force[test]).mean() < 0.05 * np.abs(force - force.mean()).mean()
    again = estimator_from_dict(ridge.to_dict())
    assert isinstance(again, RidgeThumbnail)
    np.testing.assert_allclose(again.predict_session(session), ridge.predict_session(session))
    # a refit (an interval fold) keeps the size and penalty validation chose: on the same
    # frames it is the same ridge; on others, the same size and penalty, other weights
    same = fit_ridge_thumbnails([(session, train)], [], [1, 2, 4], (ridge.size, ridge.alpha))
    np.testing.assert_allclose(same.weights, ridge.weights)
    other = fit_ridge_thumbnails([(session, test)], [], [1, 2, 4], (ridge.size, ridge.alpha))
    assert (other.size, other.alpha) == (ridge.size, ridge.alpha)
    assert not np.allclose(other.weights, ridge.weights)


def test_ridge_penalty_is_chosen_on_sessions_it_did_not_see():
    # Within each session force follows its own map of the heights; nothing carries over.
    # Folds inside a session would reward fitting that map; session folds choose a penalty
    # that shrinks towards the mean instead.
    rng = np.random.default_rng(1)
    heights = rng.normal(0, 1e-3, (300, 16))
    groups = np.repeat([0, 1, 2], 100)
    maps = rng.normal(0, 1.0, (3, 16)) * 1e3
    force = np.einsum("ij,ij->i", heights, maps[groups]) + 2.0
    within = fit_ridge(heights, force[:, None])[0]
    across = fit_ridge(heights, force[:, None], groups)[0]
    assert across.alpha > 100 * within.alpha
    unseen = rng.normal(0, 1e-3, (200, 16))
    truth = unseen @ (rng.normal(0, 1.0, 16) * 1e3) + 2.0
    error = {
        name: np.abs(r.predict(unseen)[:, 0] - truth).mean()
        for name, r in (("within", within), ("across", across))
    }
    assert error["across"] < error["within"]


def test_history_mlp_reads_the_pull_rate_that_one_frame_cannot():
    # Two stiffnesses pulled so that force rises at the same rate (k·v fixed, as in the paper's
    # protocol): at one displacement the soft tissue carries less force than the stiff one, so
    # a function of the current displacement alone must err; its recent course tells the speed.
    def ramp(name, k, v, frames=60, dt=0.1):
        t = np.arange(frames) * dt
        d = v * np.clip(t - 0.5, 0, None)
        return prepared(name, d, k * d, {"stiffness_n_per_m": k})

    train = [ramp("soft", 40.0, 0.01), ramp("stiff", 200.0, 0.002)]
    test = [ramp("soft2", 40.0, 0.01, frames=50), ramp("stiff2", 200.0, 0.002, frames=50)]
    fitted = fit_baselines(all_frames(train), history_offsets=[4, 2, 0], seed=0)
    history, linear = fitted["mlp_displacement_history"], fitted["linear_displacement"]
    errors = {
        name: np.mean([np.abs(b.predict_session(s) - s.targets_n).mean() for s in test])
        for name, b in (("history", history), ("linear", linear))
    }
    spread = np.mean([np.abs(s.targets_n - s.targets_n.mean()).mean() for s in test])
    assert errors["history"] < 0.1 * spread and errors["history"] < 0.2 * errors["linear"]
    again = baseline_from_dict(history.to_dict())
    np.testing.assert_allclose(again.predict_session(test[0]), history.predict_session(test[0]))
    repeat = fit_baselines(all_frames(train), history_offsets=[4, 2, 0], seed=0)
    np.testing.assert_array_equal(
        repeat["mlp_displacement_history"].predict_session(test[1]),
        history.predict_session(test[1]),
    )


def test_history_features_are_causal():
    from vbfe.estimate.history_baseline import history_features

    d = np.array([1.0, np.nan, 3.0, 4.0])
    np.testing.assert_array_equal(
        history_features(d, [5, 2, 0]), [[0, 0, 1], [0, 0, 0], [0, 1, 3], [0, 0, 4]]
    )
