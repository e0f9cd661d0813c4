"""The live pipeline: stages on their own threads with newest-item mailboxes, and the live
estimator's stages (row-halved reconstruction, the network-only features) against the
sequential, full-featured path."""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
import threading
import time

import cv2
import numpy as np
import pytest

from vbfe.acquire import Acquisition
from vbfe.drivers.registry import open_rig
from vbfe.drivers.rig import RigOptions
from vbfe.drivers.samples import StereoFrame
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.estimate.baselines import AffineBaseline
from vbfe.estimate.candidates import NetworkEstimator
from vbfe.estimate.inference import FramePredictor
from vbfe.estimate.live_predictor import LivePredictor
from vbfe.estimate.model_file import ForceModel
from vbfe.estimate.pointnet import PointNetRegressor, TemporalPointNet
from vbfe.estimate.train_config import TrainConfig
from vbfe.live.estimator import STAGES, FrameEstimator, FrameWork
from vbfe.live.pipeline import Pipeline
from vbfe.live.run import LiveRun
from vbfe.recon import Reconstructor, make_pattern
from vbfe.recon.maps import depth_map_m
from vbfe.rig_config import builtin_rig
from vbfe.truth import calibration_from_rig

WAIT_S = 10.0  # generous: only a hung thread takes this long


def _live_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("vbfe-live-")]


def test_stages_overlap_the_newest_item_wins_and_stop_leaves_no_thread():
    first_taken, release_first, model_took_first = (threading.Event() for _ in range(3))
    taken: list[int] = []
    delivered: list[int] = []

    def match(item: int) -> int:
        taken.append(item)
        if item == 0:
            first_taken.set()
            assert release_first.wait(WAIT_S)
        else:  # (else the model's mailbox too would see item 0 replaced)
            assert model_took_first.wait(WAIT_S)
        return item

    def model(item: int) -> int:
        model_took_first.set()
        return item * 10

    pipeline = Pipeline([("match", match), ("model", model)], delivered.append)
    pipeline.start()
    pipeline.put(0)
    assert first_taken.wait(WAIT_S)
    for item in range(1, 6):  # the first stage is busy: each replaces the one before
        pipeline.put(item)
    release_first.set()
    pipeline.stop()  # the items in flight drain first
    assert taken == [0, 5] and delivered == [0, 50]
    assert pipeline.skipped == 4 and pipeline.error is None
    assert not _live_threads()


def test_concurrent_stages_each_work_on_their_own_item():
    model_busy, match_started_next = threading.Event(), threading.Event()
    delivered: list[int] = []

    def match(item: int) -> int:
        if item == 1:
            assert model_busy.wait(WAIT_S)
            match_started_next.set()
        return item

    def model(item: int) -> int:
        if item == 0:
            model_busy.set()
            assert match_started_next.wait(WAIT_S)  # both stages hold an item at once
        return item

    pipeline = Pipeline([("match", match), ("model", model)], delivered.append)
    pipeline.start()
    pipeline.put(0)
    assert model_busy.wait(WAIT_S)
    pipeline.put(1)
    pipeline.stop()
    assert delivered == [0, 1] and pipeline.skipped == 0 and not _live_threads()


def test_a_failing_stage_halts_the_pipeline_and_names_itself():
    pipeline = Pipeline(
        [("reconstruct", lambda item: 1 / item), ("model", lambda x: x)], lambda x: None
    )
    pipeline.start()
    pipeline.put(0)
    pipeline.stop()
    assert pipeline.error == "reconstruct: division by zero" and not _live_threads()


@pytest.fixture(scope="module")
def bench_frames():
    """Three 320x180 stereo frames of the simulated bench (sensor noise apart) and its
    calibration."""
    rig = default_rig(320, 180)
    tissue = TissueSurface(texture=tissue_texture(np.random.default_rng(3)))
    pattern = make_pattern(rig.projector.width, rig.projector.height)
    pairs = [
        render_scene(rig, tissue, pattern, rng=np.random.default_rng(seed)) for seed in range(3)
    ]
    frames = [
        StereoFrame(left=p.left, right=p.right, seq=k, t_device_ns=k, t_host_ns=k)
        for k, p in enumerate(pairs)
    ]
    return frames, calibration_from_rig(rig)


def _model(estimator, name: str, n_points: int = 64) -> ForceModel:
    config = TrainConfig(n_points=n_points, conv_channels=[8, 16], head_channels=[8])
    return ForceModel(config=config, estimators={name: estimator}, selected=name)


def _pointnet(seed: int = 0) -> ForceModel:
    torch = pytest.importorskip("torch")
    torch.manual_seed(seed)
    network = PointNetRegressor(conv_channels=[8, 16], head_channels=[8], rest_depth=True)
    return _model(NetworkEstimator(network.eval(), 64), "pointnet")


def test_the_pipeline_gives_the_sequential_estimates(bench_frames):
    frames, calibration = bench_frames
    sequential = FrameEstimator(_pointnet(), calibration)
    expected = [sequential.estimate(frame) for frame in frames]
    staged = FrameEstimator(_pointnet(), calibration)
    delivered, ready = [], threading.Semaphore(0)
    pipeline = Pipeline(staged.stages(), lambda e: (delivered.append(e), ready.release()))
    pipeline.start()
    for frame in frames:  # one at a time: none skipped
        pipeline.put(FrameWork(frame))
        assert ready.acquire(timeout=WAIT_S)
    pipeline.stop()
    assert [e.frame_seq for e in delivered] == [0, 1, 2]
    for got, want in zip(delivered, expected, strict=False):
        assert np.isfinite(want.force_n).all() and got.n_points == want.n_points > 1000
        np.testing.assert_allclose(got.force_n, want.force_n, rtol=1e-6)
        assert len(got.stage_s) == len(STAGES)


def _clouds(bench_frames) -> list[np.ndarray]:
    frames, calibration = bench_frames
    reconstructor = Reconstructor(calibration)
    return [reconstructor.process(f.left, f.right).points for f in frames]


@pytest.mark.parametrize("kind", ["pointnet", "temporal", "displacement baseline"])
def test_live_features_give_the_full_predictors_estimates(bench_frames, kind):
    torch = pytest.importorskip("torch")
    torch.manual_seed(1)
    if kind == "pointnet":
        model = _pointnet(1)
    elif kind == "temporal":
        network = TemporalPointNet(
            n_frames=2, conv_channels=[8, 16], head_channels=[8], rest_depth=True
        )
        torch.nn.init.normal_(network.motion_head[-1].weight)  # the window counts
        model = _model(NetworkEstimator(network.eval(), 64, (1, 0), "temporal"), "temporal")
    else:
        model = _model(
            AffineBaseline("displacement", np.array([30.0]), np.array([0.1])), "displacement"
        )
    full, live = FramePredictor(model, seed=5), LivePredictor(model, seed=5)
    clouds = _clouds(bench_frames)
    for points in clouds + clouds[::-1]:
        want = full.predict(points)
        np.testing.assert_allclose(
            live.model_force(live.prepare(points)), want, rtol=1e-5, atol=1e-7
        )


def test_row_halved_reconstruction_sees_the_same_surface(bench_frames):
    frames, calibration = bench_frames
    frame = frames[0]
    full = Reconstructor(calibration).process(frame.left, frame.right)
    halved = FrameEstimator(_pointnet(), calibration, row_scale=0.5)
    half_calibration = halved.reconstructor.calibration
    assert half_calibration.image_size == (320, 90)
    small = [
        cv2.resize(im, (320, 90), interpolation=cv2.INTER_AREA) for im in (frame.left, frame.right)
    ]
    half = halved.reconstructor.process(*small)
    assert 0.45 < len(half.points) / len(full.points) < 0.55
    # the live stage averages the row pairs itself (one weighted sum): the same pixels as
    # INTER_AREA, so the same cloud
    live = halved.reconstruct(FrameWork(frame))
    np.testing.assert_array_equal(live.points, half.points)
    np.testing.assert_array_equal(live.colors, half.colors)
    # each halved row against the mean depth of its two full rows: nearly every pixel alike
    z_full = depth_map_m(full.disparity, calibration)
    z_pairs = (z_full[0::2] + z_full[1::2]) / 2
    z_half = depth_map_m(half.disparity, half_calibration)
    both = np.isfinite(z_pairs) & np.isfinite(z_half)
    dz = np.abs(z_half - z_pairs)[both]
    assert both.sum() > 0.4 * np.isfinite(z_half).sum()
    assert np.median(dz) < 1e-5 and np.percentile(dz, 95) < 1e-3  # metres; z is about 0.06
    # the same extent across and along the rows (a wrong row geometry would stretch y)
    for axis in (0, 1):
        lo_f, hi_f = np.percentile(full.points[:, axis], [5, 95])
        lo_h, hi_h = np.percentile(half.points[:, axis], [5, 95])
        assert abs(lo_h - lo_f) < 0.01 * (hi_f - lo_f) and abs(hi_h - hi_f) < 0.01 * (hi_f - lo_f)


def test_a_frame_reaching_the_run_too_late_is_skipped_not_estimated_but_the_rest_never(
    bench_frames,
):
    frames, calibration = bench_frames
    run = LiveRun(
        Acquisition(open_rig(builtin_rig(), RigOptions(realtime=False))),
        FrameEstimator(_pointnet(), calibration),
        max_frame_age_s=0.25,
    )
    now = time.monotonic_ns()
    first, late, fresh = (
        dataclasses.replace(frames[k], t_host_ns=t)
        for k, t in ((0, now - 10**9), (1, now - 10**9), (2, now))
    )
    run.on_start(run.acquisition)
    run.on_frames([first])  # late too, but the rest reference: estimated all the same
    run.on_frames([late])
    run.on_frames([fresh])
    run.on_stop(run.acquisition)  # the frames in flight drain
    status = run.status()
    assert [e.frame_seq for e in run.estimates] == [0, 2]
    assert (status.frames, status.estimates, status.skipped) == (3, 2, 1)
    assert not _live_threads()


@pytest.mark.skipif(sys.platform != "linux", reason="a thread has a priority of its own on Linux")
def test_beside_a_recording_the_stages_run_at_a_lower_priority_than_the_process():
    base = os.getpriority(os.PRIO_PROCESS, 0)
    nice: dict[bool, list[int]] = {True: [], False: []}
    for beside in (True, False):
        done = threading.Event()

        def stage(item: int, beside: bool = beside, done: threading.Event = done) -> int:
            nice[beside].append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
            done.set()
            return item

        pipeline = Pipeline([("a", stage), ("b", stage)], lambda item: None, beside)
        pipeline.start()
        pipeline.put(1)
        assert done.wait(WAIT_S)
        pipeline.stop()
    assert nice[True] == [min(base + 10, 19)] * 2 and nice[False] == [base] * 2
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == base  # caller's kept


def test_foxglove_overflow_lines_name_each_client_once_and_detach_restores_the_logger():
    from vbfe.live.foxglove_overflow import SDK_LOGGER, Overflows

    logger = logging.getLogger(SDK_LOGGER)
    logger.setLevel(logging.WARNING)
    overflows = Overflows()
    overflows.attach()
    try:
        assert logger.level == logging.INFO  # pyo3-log passes INFO lines on only then
        for address in ("127.0.0.1:5001", "127.0.0.1:5002", "127.0.0.1:5001"):
            logger.info("outbox for client %s full", address)
        logger.info("client 127.0.0.1:5003 connected")
        assert overflows.new() == ["127.0.0.1:5001", "127.0.0.1:5002"]
        assert overflows.new() == []
    finally:
        overflows.detach()
    assert logger.level == logging.WARNING and overflows not in logger.handlers
    logger.setLevel(logging.NOTSET)
