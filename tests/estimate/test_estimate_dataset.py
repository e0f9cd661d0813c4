"""Dataset building: ROI, sampling, skipped frames, displacement, session split."""

import numpy as np
import pytest

from vbfe.common.errors import EstimateError
from vbfe.estimate.dataset import FrameBatches, prepare_session, prepare_sessions
from vbfe.estimate.depth_image import DepthChangeImage, thumbnails
from vbfe.estimate.displacement import MIN_CELL_POINTS, DisplacementGrid
from vbfe.estimate.preparation import crop_roi, force_target, sample_points
from vbfe.estimate.sources import SessionClouds
from vbfe.estimate.splits import (
    SessionSplit,
    split_by_ranges,
    split_by_session,
    split_by_time,
    split_folds,
)
from vbfe.estimate.synthetic import synthetic_session, synthetic_sessions
from vbfe.estimate.train_config import TrainConfig


def small_config(**kw):
    return TrainConfig(n_points=64, pool_factor=2, **kw)


def test_roi_keeps_finite_points_inside_the_region():
    points = np.array(
        [[0, 0, 0.08], [0.05, 0, 0.08], [np.nan, 0, 0.08], [0, np.inf, 0.08], [0.001, 0.001, 0.081]]
    )
    assert len(crop_roi(points, small_config())) == 3
    radius = crop_roi(points, small_config(roi="radius", roi_radius_m=0.01))
    assert len(radius) == 2 and np.all(radius[:, 0] < 0.01)
    box = crop_roi(points, small_config(roi="box", roi_box_m=[0.01, -1, 0, 1, 1, 1]))
    np.testing.assert_array_equal(box, [[0.05, 0, 0.08]])


def test_sampling_is_without_replacement_unless_the_cloud_is_too_small():
    rng = np.random.default_rng(0)
    points = np.arange(30.0).reshape(10, 3)
    few = sample_points(points, 6, rng)
    assert len(np.unique(few[:, 0])) == 6
    padded = sample_points(points, 25, rng)
    assert padded.shape == (25, 3) and set(padded[:, 0]) <= set(points[:, 0])


def test_force_target_magnitude_or_axes():
    forces = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, -2.0]])
    np.testing.assert_allclose(force_target(forces, "magnitude"), [[5.0], [2.0]])
    np.testing.assert_allclose(force_target(forces, "xyz"), forces)
    np.testing.assert_allclose(force_target(forces, "-z"), [[0.0], [2.0]])
    np.testing.assert_allclose(force_target(forces, "y"), [[4.0], [0.0]])
    with pytest.raises(EstimateError, match="target"):
        TrainConfig(target="w")


def test_empty_and_nan_clouds_are_skipped_and_counted():
    session = synthetic_session(
        "s", 80.0, 0.005, np.random.default_rng(1), fps=4, points_per_side=12
    )
    session.clouds[2] = np.zeros((0, 3))
    session.clouds[5] = np.full((100, 3), np.nan)
    session.forces_n[7] = np.nan
    prepared = prepare_session(session, small_config())
    assert prepared.n_skipped == 3
    assert prepared.n_used == session.n_frames - 3 == len(prepared.pools)
    assert prepared.pools.shape[1:] == (128, 4) and np.isfinite(prepared.pools).all()
    kept_times = set(prepared.times_ns.tolist())
    assert not kept_times & {int(session.times_ns[i]) for i in (2, 5, 7)}


def test_a_session_without_any_usable_cloud_is_an_error_naming_it():
    empty = SessionClouds(
        "broken-run", [np.full((5, 3), np.nan)] * 3, np.ones((3, 3)), np.arange(3, dtype=np.int64)
    )
    with pytest.raises(EstimateError, match="broken-run"):
        prepare_sessions([empty], small_config())


def test_displacement_grid_measures_a_known_bump():
    side = np.linspace(-0.01, 0.01, 60)
    gx, gy = [g.ravel() for g in np.meshgrid(side, side)]
    flat = np.column_stack([gx, gy, np.full_like(gx, 0.08)])
    bumped = flat.copy()
    bumped[:, 2] -= 0.003 * np.exp(-(gx**2 + gy**2) / (2 * 0.003**2))
    grid = DisplacementGrid(flat, cells=10)
    assert grid.peak_displacement_m(flat) == 0.0
    peak = grid.peak_displacement_m(bumped)
    assert 0.0015 < peak <= 0.003
    twice = flat.copy()
    twice[:, 2] = 2 * bumped[:, 2] - flat[:, 2]
    assert grid.peak_displacement_m(twice) == pytest.approx(2 * peak, rel=1e-3)
    spiked = flat.copy()  # one outlier cell (e.g. an occlusion edge) is not a displacement
    spiked[(gx > 0.008) & (gy > 0.008), 2] -= 0.005
    assert grid.peak_displacement_m(spiked) == 0.0


def test_displacement_grid_cells_hold_the_median_depth_of_their_points():
    """The compiled per-cell median against numpy's, cell by cell, on a scattered cloud with
    cells of even and odd counts, sparse cells (NaN) and points outside the grid."""
    rng = np.random.default_rng(4)
    reference = np.column_stack([rng.uniform(-0.01, 0.01, (4000, 2)), rng.normal(0.06, 1e-3, 4000)])
    grid = DisplacementGrid(reference, cells=12)
    cloud = np.column_stack([rng.uniform(-0.012, 0.012, (3000, 2)), rng.normal(0.06, 1e-3, 3000)])
    ij = np.floor((cloud[:, :2] - grid._lo) / grid._size).astype(int)
    want = np.full((12, 12), np.nan)
    for i in range(12):
        for j in range(12):
            z = cloud[(ij[:, 0] == i) & (ij[:, 1] == j), 2]
            if len(z) >= MIN_CELL_POINTS:
                want[i, j] = np.median(z)
    got = grid.depth_map(cloud)
    assert np.isnan(want).sum() < 10 and np.array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_array_equal(got, want)
    sparse = grid.depth_map(cloud[:200])  # about 1.4 points per cell: most are NaN
    assert 0 < np.isfinite(sparse).sum() < 40


def test_displacement_grows_with_force_in_prepared_sessions():
    session = synthetic_session("s", 40.0, 0.01, np.random.default_rng(2), fps=3, noise_m=0)
    prepared = prepare_session(session, small_config())
    force = prepared.targets_n[:, 0]
    assert np.corrcoef(force, prepared.displacement_m)[0, 1] > 0.95


def test_frame_stride_uses_every_kth_frame():
    session = synthetic_session(
        "s", 200.0, 0.002, np.random.default_rng(3), fps=4, points_per_side=10
    )
    prepared = prepare_session(session, small_config(frame_stride=3))
    np.testing.assert_array_equal(prepared.times_ns, session.times_ns[::3])


def test_split_is_by_session_without_leakage_and_stratified():
    sessions = prepare_sessions(
        synthetic_sessions(repeats=4, fps=1, points_per_side=10), small_config()
    )
    split = split_by_session(sessions, val_fraction=0.25, test_fraction=0.25, seed=5)
    parts = [set(split.train), set(split.val), set(split.test)]
    assert sum(len(p) for p in parts) == len(sessions) == len(set.union(*parts))
    assert not (parts[0] & parts[1] or parts[0] & parts[2] or parts[1] & parts[2])
    assert len(split.val) == len(split.test) == 3
    by_name = {s.name: s.condition for s in sessions}
    for part in (split.val, split.test):  # one repeat of each of the three conditions
        assert len({by_name[n] for n in part}) == 3
    # frames of one session never end up on both sides
    train_frames = split.frames("train", sessions)
    assert {s.name for s, _ in train_frames} == parts[0]
    assert len(FrameBatches(train_frames, 8)) == sum(
        s.n_used for s in sessions if s.name in parts[0]
    )
    assert split_by_session(sessions, 0.25, 0.25, seed=5) == split


def test_split_by_session_gives_every_protocol_its_share_of_validation():
    """Freehand trials, each of its own tissue (one condition per session), are validated on
    as the pull-and-hold sessions are: each protocol is split apart."""
    sessions = prepare_sessions(
        synthetic_sessions(repeats=5, fps=1, points_per_side=10), small_config()
    )
    freehand = sessions[:5]
    for k, session in enumerate(freehand):
        session.conditions.update(protocol="freehand", label=f"freehand {40 + k} N/m")
    split = split_by_session(sessions, val_fraction=0.2, test_fraction=0.0, seed=1)
    names = {s.name for s in freehand}
    assert len(names & set(split.val)) == 1 and len(names & set(split.train)) == 4
    assert len(set(split.val) - names) == 2  # 0.2 of the 10 pull-and-hold sessions


def test_split_keeps_one_training_session():
    sessions = prepare_sessions(
        synthetic_sessions(repeats=1, fps=1, points_per_side=10)[:2], small_config()
    )
    split = split_by_session(sessions, val_fraction=0.5, test_fraction=0.5, seed=0)
    assert len(split.train) == 1 and len(split.train) + len(split.val) + len(split.test) == 2


def test_batches_redraw_points_from_the_pool():
    sessions = prepare_sessions(
        synthetic_sessions(repeats=1, fps=2, points_per_side=12), small_config()
    )
    batches = FrameBatches([(s, np.arange(s.n_used)) for s in sessions], 64)
    rng = np.random.default_rng(0)
    ((a, ya),) = list(batches.batches(10_000, rng))
    ((b, yb),) = list(batches.batches(10_000, None))
    assert a.shape == b.shape == (len(batches), 64, 4) and ya.shape == (len(batches), 1)
    np.testing.assert_array_equal(b.numpy(), batches.pools[:, :64])
    np.testing.assert_array_equal(np.sort(yb.numpy(), 0), np.sort(ya.numpy(), 0))


def _positions(split, part, session):
    return set(split.positions(part, session).tolist())


def test_time_split_is_train_then_val_then_test_with_gaps_stated_as_frame_ranges():
    session = prepare_session(
        synthetic_session("one", 80.0, 0.005, np.random.default_rng(4), fps=30, points_per_side=10),
        small_config(),
    )
    n = session.n_used
    split = split_by_time([session], val_fraction=0.2, test_fraction=0.2, gap_frames=12)
    assert split.kind == "time" and split.train == split.val == split.test == ["one"]
    # one contiguous range per part, in time order: a press cannot hide in training
    train_r, val_r, test_r = (split.blocks[p]["one"] for p in ("train", "val", "test"))
    assert len(train_r) == len(val_r) == len(test_r) == 1
    assert train_r[0][0] == 0 and test_r[0][1] == n
    assert val_r[0][0] - train_r[0][1] == 12 and test_r[0][0] - val_r[0][1] == 12  # left out
    train, val, test = (_positions(split, p, session) for p in ("train", "val", "test"))
    assert max(train) < min(val) and max(val) < min(test) and len(test) == n - int(0.8 * n)
    again = SessionSplit.from_dict(split.to_dict())
    assert _positions(again, "test", session) == test
    assert f"test {test_r[0][0]}:{n}" in again.describe() and "gap 12" in again.describe()


def test_stated_ranges_are_frame_numbers_and_must_not_overlap():
    raw = synthetic_session("r", 80.0, 0.005, np.random.default_rng(4), fps=30, points_per_side=10)
    raw.clouds[5] = np.full((30, 3), np.nan)  # unusable: positions and frame numbers differ
    session = prepare_session(raw, small_config())
    split = split_by_ranges([session], {"train": [0, 40], "val": [50, 60], "test": [70, 90]})
    assert session.frame_index[sorted(_positions(split, "val", session))].tolist() == list(
        range(50, 60)
    )
    assert split.blocks["train"]["r"] == [[0, 40]]  # as stated (frame 5 is simply not used)
    with pytest.raises(EstimateError, match="overlap"):
        split_by_ranges([session], {"train": [0, 40], "val": [30, 60], "test": []})
    with pytest.raises(EstimateError, match="no usable frame in the training range"):
        split_by_ranges([session], {"train": [5000, 6000], "val": [], "test": []})


def test_folds_test_every_block_once_with_gaps():
    session = prepare_session(
        synthetic_session("f", 80.0, 0.005, np.random.default_rng(4), fps=30, points_per_side=10),
        small_config(),
    )
    splits = split_folds([session], 5, gap_frames=3)
    tested = [_positions(s, "test", session) for s in splits]
    assert set().union(*tested) == set(range(session.n_used))
    assert sum(len(t) for t in tested) == session.n_used
    for split, test in zip(splits, tested, strict=False):
        train, val = _positions(split, "train", session), _positions(split, "val", session)
        assert train and val and not (train & val or train & test or val & test)
        for i in train:
            assert min(abs(j - i) for j in val | test) > 3
    with pytest.raises(EstimateError, match="at least 3 folds"):
        split_folds([session], 2, 0)


def test_depth_change_image_and_its_thumbnails():
    side = np.linspace(-0.01, 0.01, 64)
    gx, gy = [g.ravel() for g in np.meshgrid(side, side)]
    rest = np.column_stack([gx, gy, np.full(gx.shape, 0.08)])
    image = DepthChangeImage(rest, 8)
    pressed = rest.copy()
    pressed[(gx > 0) & (gy > 0), 2] -= 0.002  # one quadrant 2 mm closer
    total, count = image.sums_counts(pressed)
    change = np.where(count > 0, total / np.maximum(count, 1), 0)
    assert count.sum() > 0.9 * len(rest)
    np.testing.assert_allclose(np.sort(np.unique(change.round(6))), [-0.002, 0.0], atol=1e-9)
    two = thumbnails(total[None], count[None], 2)[0]
    np.testing.assert_allclose(np.sort(two), [-0.002, 0, 0, 0], atol=2e-4)
    np.testing.assert_allclose(
        thumbnails(total[None], count[None], 8)[0], change.ravel(), atol=1e-9
    )


def test_temporal_window_is_causal_and_starts_with_the_rest_frame():
    session = prepare_session(
        synthetic_session("w", 200.0, 0.01, np.random.default_rng(5), fps=10, points_per_side=8),
        small_config(),
    )
    positions = np.array([0, 3, 20])
    batches = FrameBatches([(session, positions)], 16, window=[6, 3, 0])
    rows = batches.frame_indices(np.arange(3))
    np.testing.assert_array_equal(rows, [[0, 0, 0, 0], [0, 0, 0, 3], [0, 14, 17, 20]])
    points, y = next(batches.batches(8, None))
    assert points.shape == (3, 4, 16, 4)
    np.testing.assert_array_equal(points[2, 3].numpy(), session.pools[20, :16])
    np.testing.assert_allclose(y.numpy(), session.targets_n[positions], rtol=1e-6)
    assert TrainConfig(temporal_frames=3, temporal_span_frames=6).temporal_window == [6, 3, 0]


def test_history_window_is_set_in_the_config_and_checked():
    assert TrainConfig(history_frames=3, history_span_frames=6).history_window == [6, 3, 0]
    assert TrainConfig(history_frames=0).history_window == []
    for bad in (dict(history_frames=1), dict(history_frames=5, history_span_frames=3)):
        with pytest.raises(EstimateError, match="history_frames"):
            TrainConfig(**bad)


def test_sessions_prepared_in_worker_processes_equal_those_prepared_here(tmp_path, monkeypatch):
    """Files are prepared in spawned processes once one session took longer than a worker's
    start: the same sessions, in the caller's order."""
    import vbfe.estimate.dataset as dataset
    from vbfe.estimate.importing import write_clouds

    paths = []
    for k, s in enumerate(synthetic_sessions(repeats=1, seed=4, fps=2, points_per_side=10)):
        paths.append(
            write_clouds(
                tmp_path / f"s{k}.clouds.h5", s.clouds, s.times_ns, s.forces_n, s.conditions, {}
            )
        )
    here = prepare_sessions(paths, small_config())
    monkeypatch.setattr(dataset, "WORKER_START_S", 0.0)  # every session counts as slow
    seen = []
    spawned = prepare_sessions(
        paths, small_config(), lambda stage, done, total: seen.append(done), workers=2
    )
    assert [s.name for s in spawned] == [s.name for s in here] == [str(p) for p in paths]
    for a, b in zip(here, spawned, strict=True):
        np.testing.assert_array_equal(a.pools, b.pools)
        np.testing.assert_array_equal(a.targets_n, b.targets_n)
        np.testing.assert_array_equal(a.image_sum, b.image_sum)
    assert seen == [1, 2, 3]
