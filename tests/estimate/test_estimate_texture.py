"""Texture tracking: a textured surface moved sideways by a known shift, rendered with the
projected pattern and reconstructed, and Hooke's law on the tracked 3D displacement."""

import threading

import numpy as np
import pytest

from tests.texture_reference import reference_peak
from vbfe.common.errors import EstimateError
from vbfe.drivers.samples import StereoFrame
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import Plane, UniformAlbedo, tissue_texture
from vbfe.estimate.baselines import AffineBaseline
from vbfe.estimate.candidates import CANDIDATES, TEXTURE_FEATURE
from vbfe.estimate.dataset import prepare_session
from vbfe.estimate.inference import FramePredictor
from vbfe.estimate.live_predictor import LivePredictor
from vbfe.estimate.model_file import ForceModel, load_model
from vbfe.estimate.sources import SessionClouds
from vbfe.estimate.texture_motion import TextureMotion
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.training import train
from vbfe.live.estimator import STAGES, FrameEstimator, FrameWork
from vbfe.live.pipeline import Pipeline
from vbfe.recon import Reconstructor, make_pattern
from vbfe.truth import calibration_from_rig

DISTANCE_M = 0.06
SHIFTS_M = np.array(
    [[0.0, 0.0, 0.0], [0.4e-3, -0.3e-3, 0.0], [1.2e-3, -0.6e-3, 0.0], [-1.0e-3, 1.8e-3, 0.4e-3]]
)  # the first is the rest pose
STIFFNESS_N_PER_M = 900.0  # force of each pose: this times its shift's length


@pytest.fixture(scope="module")
def shifted_clouds():
    """(points, colours) of a textured plane at each of ``SHIFTS_M`` (the texture moves with
    it), rendered at 640×360 with the projected pattern and reconstructed; of a plain plane at
    rest; and the textured frames with their calibration."""
    rig = default_rig(640, 360)
    pattern = make_pattern(rig.projector.width, rig.projector.height)
    calibration = calibration_from_rig(rig)
    reconstructor = Reconstructor(calibration)
    texture = tissue_texture(np.random.default_rng(3))

    def render(shift, albedo, seed):  # each frame its own sensor noise
        plane = Plane(np.eye(3), np.array([0.0, 0.0, DISTANCE_M]) + shift, texture=albedo)
        pair = render_scene(rig, plane, pattern, rng=np.random.default_rng(seed))
        return StereoFrame(
            left=pair.left, right=pair.right, seq=seed, t_device_ns=seed, t_host_ns=seed
        )

    def cloud(frame):
        reconstructed = reconstructor.process(frame.left, frame.right)
        return reconstructed.points, reconstructed.colors

    frames = [render(shift, texture, seed) for seed, shift in enumerate(SHIFTS_M)]
    plain = render(SHIFTS_M[0], UniformAlbedo((0.72, 0.74, 0.95)), len(SHIFTS_M))
    return [cloud(frame) for frame in frames], cloud(plain), (frames, calibration)


def test_tracking_recovers_a_known_shift(shifted_clouds):
    clouds, _, _ = shifted_clouds
    motion, reason = TextureMotion.from_rest(*clouds[0])
    assert motion is not None, reason
    peaks = []
    for (points, colors), shift in zip(clouds[1:], SHIFTS_M[1:], strict=False):
        field = motion.displacement_m(points, colors)
        seen = np.isfinite(field).all(axis=-1)
        assert seen.mean() > 0.8
        # the whole surface moved by the shift: sideways (what a depth map cannot see) and in
        # depth, each within a fifth of a millimetre (a pixel is 0.13 mm at 60 mm)
        np.testing.assert_allclose(np.median(field[seen], axis=0), shift, atol=2e-4)
        peaks.append(motion.peak_displacement_m(points, colors))
    lengths = np.linalg.norm(SHIFTS_M[1:], axis=1)
    assert np.all(np.argsort(peaks) == np.argsort(lengths))
    assert np.all((np.array(peaks) > 0.9 * lengths) & (np.array(peaks) < 1.6 * lengths))


def test_plain_surfaces_and_clouds_without_colours_are_not_tracked(shifted_clouds):
    clouds, (plain_points, plain_colors), _ = shifted_clouds
    points, colors = clouds[0]
    assert TextureMotion.from_rest(points, None) == (None, "the clouds carry no colours")
    for rest in ((plain_points, plain_colors), (points, np.zeros_like(colors))):  # as imported
        motion, reason = TextureMotion.from_rest(*rest)
        assert motion is None and reason.startswith("the surface shows no texture to track")
    motion, _ = TextureMotion.from_rest(points, colors)
    assert np.isnan(motion.peak_displacement_m(*clouds[1][:1], None))


def _sessions(clouds, with_colours=True):
    """Three sessions through the shifted poses in different orders, from rest, with the
    force of a spring pulled by each shift."""
    sessions = []
    for k, order in enumerate(([0, 1, 2, 3], [0, 3, 2, 1], [0, 2, 3, 1])):
        force = STIFFNESS_N_PER_M * np.linalg.norm(SHIFTS_M[order], axis=1)
        sessions.append(
            SessionClouds(
                f"plane{k}",
                [clouds[i][0] for i in order],
                np.column_stack([force, np.zeros((len(order), 2))]),
                np.arange(len(order), dtype=np.int64) * 10**8,
                point_colors=[clouds[i][1] for i in order] if with_colours else None,
            )
        )
    return sessions


def test_texture_hooke_is_trained_stored_and_used_frame_by_frame(shifted_clouds, tmp_path):
    clouds, _, (frames, calibration) = shifted_clouds
    config = TrainConfig(model="hooke_texture", val_fraction=1 / 3, history_frames=0, threads=1)
    result = train(_sessions(clouds), tmp_path / "model.pt", config)
    assert result.selected == "hooke_texture_3d"
    # the shifts are mostly sideways: the depth-only Hooke's law cannot follow the force
    assert result.val_mae_n["hooke_texture_3d"] < 0.4 * result.val_mae_n["hooke"]
    model = load_model(result.model_path)
    estimator = model.estimators["hooke_texture_3d"]
    # read back from the file: Hooke's law on the texture (its peak over-reads a little)
    assert estimator.feature == "texture_displacement_m" and estimator.intercept == 0
    assert 0.5 * STIFFNESS_N_PER_M < estimator.slope[0] < 1.1 * STIFFNESS_N_PER_M
    predictor = FramePredictor(model)
    forces = [predictor.predict(points, colors)[0] for points, colors in clouds]
    want = STIFFNESS_N_PER_M * np.linalg.norm(SHIFTS_M, axis=1)
    assert np.abs(np.array(forces) - want).mean() < 0.15 * want.mean()
    # vbfe live reconstructs the frames itself and gives the same forces
    live = FrameEstimator(model, calibration)
    np.testing.assert_allclose(
        [live.estimate(frame).force_n[0] for frame in frames], forces, rtol=1e-6
    )
    # with its rows averaged in pairs ([live] row_scale = 0.5) the grid's rows are twice as
    # far apart; the forces stay near the spring's (measured: 11 % of the mean force)
    halved = FrameEstimator(model, calibration, row_scale=0.5)
    forces = [halved.estimate(frame).force_n[0] for frame in frames]
    assert np.abs(np.array(forces) - want).mean() < 0.2 * want.mean()
    with pytest.raises(
        EstimateError, match="reads the tissue's texture, but the clouds carry no colours"
    ):
        FramePredictor(model).predict(clouds[0][0])


def test_texture_hooke_needs_coloured_textured_clouds(shifted_clouds, tmp_path):
    clouds, _, _ = shifted_clouds
    config = TrainConfig(model="hooke_texture", val_fraction=1 / 3, history_frames=0, threads=1)
    with pytest.raises(EstimateError, match="needs training clouds with the colours"):
        train(_sessions(clouds, with_colours=False), tmp_path / "model.pt", config)
    assert not (tmp_path / "model.pt").exists()


def test_the_fast_texture_feature_keeps_the_reference(shifted_clouds):
    """The compiled grid and one-pass blurs give today's feature within 2 %, on the rendered
    shifts and on a local pull (the middle of the view moved, the rest still)."""
    clouds, _, _ = shifted_clouds
    rest_points, rest_colors = clouds[0]
    motion, _ = TextureMotion.from_rest(rest_points, rest_colors)
    pulled_points = np.array(clouds[0][0], np.float64)
    centre = np.nanmedian(pulled_points, axis=0)
    reach = np.exp(-np.sum((pulled_points[:, :2] - centre[:2]) ** 2, axis=1) / (2 * 0.004**2))
    pulled_points += reach[:, None] * np.array([0.8e-3, 0.0, -0.5e-3])
    frames = clouds[1:] + [(pulled_points, clouds[0][1])]
    fast = [motion.peak_displacement_m(points, colors) for points, colors in frames]
    reference = [reference_peak(rest_points, rest_colors, p, c) for p, c in frames]
    assert np.all(np.array(reference) > 3e-4)
    np.testing.assert_allclose(fast, reference, rtol=0.02)


def test_live_computes_only_the_texture_and_gives_the_offline_estimates(shifted_clouds):
    """Hooke's law on the texture without a novelty flag: ``vbfe live`` computes the texture's
    displacement alone, and its forces are the offline preparation's, frame by frame."""
    clouds, _, (frames, calibration) = shifted_clouds
    name = CANDIDATES["hooke_texture"]
    hooke = AffineBaseline(name, np.array([STIFFNESS_N_PER_M]), np.array([0.0]), TEXTURE_FEATURE)
    model = ForceModel(
        config=TrainConfig(model="hooke_texture"), selected=name, estimators={name: hooke}
    )
    session = prepare_session(_sessions(clouds)[1], model.config)
    offline = model.predict_session(session)[:, 0]
    assert np.all(offline[1:] > 0.2)  # newtons: every moved pose is seen
    live = LivePredictor(model)
    order = [0, 3, 2, 1]  # the session's poses
    features = [live.prepare(*clouds[i]) for i in order]
    assert all(len(f.pool) == 0 and np.isnan(f.displacement_m) for f in features)
    forces = [live.model_force(f)[0] for f in features]
    np.testing.assert_allclose(forces, offline, rtol=1e-6)
    estimator = FrameEstimator(model, calibration)
    np.testing.assert_allclose(
        [estimator.estimate(frames[i]).force_n[0] for i in order], offline, rtol=1e-6
    )
    # vbfe live's pipeline reconstructs and prepares each frame on one thread: the same forces
    staged = FrameEstimator(model, calibration)
    assert [name for name, _ in staged.stages()] == ["reconstruct+prepare", "model"]
    delivered, ready = [], threading.Semaphore(0)
    pipeline = Pipeline(staged.stages(), lambda e: (delivered.append(e), ready.release()))
    pipeline.start()
    for i in order:  # one at a time: none skipped
        pipeline.put(FrameWork(frames[i]))
        assert ready.acquire(timeout=60)
    pipeline.stop()
    np.testing.assert_allclose([e.force_n[0] for e in delivered], offline, rtol=1e-6)
    assert all(len(e.stage_s) == len(STAGES) for e in delivered)


def test_live_searching_the_rest_depths_gives_the_offline_estimates(shifted_clouds):
    """With ``[live] depth_margin_mm`` the matcher searches, after the rest frame, only its
    depths ± the margin: fewer disparities, and the forces stay the offline preparation's."""
    clouds, _, (frames, calibration) = shifted_clouds
    name = CANDIDATES["hooke_texture"]
    hooke = AffineBaseline(name, np.array([STIFFNESS_N_PER_M]), np.array([0.0]), TEXTURE_FEATURE)
    model = ForceModel(
        config=TrainConfig(model="hooke_texture"), selected=name, estimators={name: hooke}
    )
    offline = model.predict_session(prepare_session(_sessions(clouds)[1], model.config))[:, 0]
    estimator = FrameEstimator(model, calibration, depth_margin_mm=10.0)
    whole = estimator.reconstructor.params.num_disparities
    forces = [estimator.estimate(frames[i]).force_n[0] for i in (0, 3, 2, 1)]
    assert estimator.reconstructor.searched.num_disparities < whole  # set after the rest frame
    np.testing.assert_allclose(forces, offline, rtol=0.02)


def test_a_cloud_in_two_patches_far_apart_is_tracked():
    """Two textured patches 100 pixels apart (a tool across the view, or an imported cloud
    cut by a depth range): the grid between them has no weight at all, and the feature is
    still computed (a shift of the second patch is seen, the still cloud reads ~0)."""
    rng = np.random.default_rng(5)
    v, u = np.mgrid[0:60, 0:220].astype(np.float64)
    keep = (u < 60) | (u >= 160)
    f, z = 500.0, 0.06
    points = np.column_stack([u[keep] / f * z, v[keep] / f * z, np.full(keep.sum(), z)])
    texture = rng.integers(60, 200, size=(60, 220)).astype(np.uint8)
    colors = np.repeat(texture[keep][:, None], 3, axis=1)
    motion, reason = TextureMotion.from_rest(points, colors)
    assert motion is not None, reason
    assert motion.peak_displacement_m(points, colors) < 1e-5
    pushed = points.copy()
    pushed[points[:, 0] > 100 / f * z, 2] -= 1e-3  # the second patch 1 mm nearer
    assert 0.5e-3 < motion.peak_displacement_m(pushed, colors) < 1.5e-3
