"""PointNet normalisation and network: centred, in the unit sphere, blind to point order."""

import numpy as np
import pytest
import torch
from scipy.spatial.distance import pdist

from vbfe.common.errors import EstimateError
from vbfe.estimate.pointnet import (
    PointNetRegressor,
    TemporalPointNet,
    diameter,
    normalize_clouds,
    shared_mlp_pooled,
    weighted_centroid,
)
from vbfe.estimate.rest_depth import RestDepth


@pytest.fixture
def clouds():
    rng = np.random.default_rng(3)
    raw = rng.normal(size=(4, 300, 3)) * [0.01, 0.02, 0.005] + [0.0, 0.01, 0.08]
    return torch.tensor(raw, dtype=torch.float32)


def test_diameter_is_the_exact_largest_pairwise_distance(clouds):
    rng = np.random.default_rng(4)
    ball = rng.normal(size=(1, 300, 3))
    ball /= np.linalg.norm(ball, axis=2, keepdims=True)  # every point could be a diameter end
    patch = np.concatenate([rng.uniform(-1, 1, (1, 300, 2)), rng.normal(0, 0.01, (1, 300, 1))], 2)
    for batch in (clouds, torch.tensor(ball), torch.tensor(patch)):
        expected = [pdist(c.double().numpy()).max() for c in batch]
        np.testing.assert_allclose(diameter(batch).numpy(), expected, rtol=1e-6)
    pair_and_point = torch.tensor([[[0.0, 0, 0], [3, 4, 0]], [[1.0, 1, 1], [1, 1, 1]]])
    np.testing.assert_allclose(diameter(pair_and_point).numpy(), [5.0, 0.0])


def test_normalised_clouds_are_centred_and_inside_the_unit_sphere(clouds):
    normalized, features = normalize_clouds(clouds)
    np.testing.assert_allclose(normalized.mean(dim=1).numpy(), 0, atol=1e-6)
    assert float(normalized.norm(dim=2).max()) <= 1.0
    np.testing.assert_allclose(features[:, :3].numpy(), clouds.mean(dim=1).numpy(), atol=1e-7)
    np.testing.assert_allclose(features[:, 3].numpy(), diameter(clouds).numpy())
    # scaling is by D_max, so the normalised diameter is exactly one
    np.testing.assert_allclose(diameter(normalized).numpy(), 1.0, rtol=1e-5)


def test_weighted_centroid_follows_the_weights(clouds):
    weights = torch.zeros(clouds.shape[:2])
    weights[:, 7] = 2.0
    np.testing.assert_allclose(weighted_centroid(clouds, weights).numpy(), clouds[:, 7].numpy())
    normalized, _ = normalize_clouds(clouds, weights)
    np.testing.assert_allclose(normalized[:, 7].numpy(), 0, atol=1e-6)


def test_network_output_does_not_depend_on_point_order(clouds):
    torch.manual_seed(0)
    net = PointNetRegressor(n_outputs=3, conv_channels=(16, 32), head_channels=(16,))
    net.eval()
    shuffled = clouds[:, torch.randperm(clouds.shape[1])]
    out = net(clouds)
    assert out.shape == (4, 3)
    torch.testing.assert_close(out, net(shuffled), rtol=1e-5, atol=1e-5)


def test_points_last_shared_mlp_is_the_convolutions_with_their_gradients(clouds):
    torch.manual_seed(1)
    net = PointNetRegressor(n_outputs=1, conv_channels=(16, 32), head_channels=(16,))
    twin = PointNetRegressor(n_outputs=1, conv_channels=(16, 32), head_channels=(16,))
    with torch.no_grad():  # a falling batch norm: the pooled point is then the lowest
        net.features[-2].weight[::2] *= -1
    twin.load_state_dict(net.state_dict())
    net, twin, clouds = net.double(), twin.double(), clouds.double()  # no near ties at the max
    for training in (True, True, False):  # twice: the running statistics move again
        net.train(training), twin.train(training)
        fast = shared_mlp_pooled(net.features, clouds)
        conv = twin.features(clouds.transpose(1, 2)).amax(dim=2)  # B×C×N through Conv1d
        torch.testing.assert_close(fast, conv)
        fast.square().sum().backward(), conv.square().sum().backward()
    for a, b in zip(net.features.parameters(), twin.features.parameters(), strict=True):
        assert a.grad is not None and a.grad.abs().sum() > 0
        torch.testing.assert_close(a.grad, b.grad)
    for a, b in zip(net.features.buffers(), twin.features.buffers(), strict=True):
        torch.testing.assert_close(a, b)  # batch norm's running statistics


def test_global_features_carry_the_size_that_normalisation_removes(clouds):
    torch.manual_seed(0)
    for with_features in (False, True):
        net = PointNetRegressor(
            conv_channels=(16,), head_channels=(8,), global_features=with_features
        ).eval()
        same = torch.allclose(net(clouds), net(clouds * 2.0), atol=1e-5)
        assert same is not with_features


def test_temporal_model_sees_the_window_in_order_and_shares_the_encoder(clouds):
    torch.manual_seed(0)
    net = TemporalPointNet(
        n_outputs=2, n_frames=3, conv_channels=[8, 16], head_channels=[8], dropout=0.0
    ).eval()
    single = PointNetRegressor(
        n_outputs=2, conv_channels=[8, 16], head_channels=[8], dropout=0.0
    ).eval()
    windows = clouds[:, None].repeat(1, 4, 1, 1)  # rest + 3 frames, 2 windows of the same cloud
    windows[:, 2] += torch.tensor([0.0, 0.0, -0.001])  # the tissue moves over the window
    windows[:, 3] += torch.tensor([0.0, 0.0, -0.002])
    # it starts as the single-frame network it is given, the motion correction at zero
    net.load_state_dict(single.state_dict(), strict=False)
    torch.testing.assert_close(net(windows), single(windows[:, 3]))
    torch.nn.init.normal_(net.motion_head[-1].weight)
    out = net(windows)
    assert out.shape == (4, 2) and torch.isfinite(out).all()
    shuffled = windows[:, :, torch.randperm(windows.shape[2])]
    torch.testing.assert_close(net(shuffled), out, rtol=1e-5, atol=1e-5)  # blind to point order
    reordered = windows[:, [0, 2, 1, 3]]  # the same newest cloud, another history
    assert not torch.allclose(net(reordered), out)
    assert net.hparams["n_frames"] == 3
    again = TemporalPointNet(**net.hparams)
    again.load_state_dict(net.state_dict())
    torch.testing.assert_close(again.eval()(windows), out)


def test_rest_depth_measures_a_bump_against_the_rest_surface():
    xy = np.stack(
        np.meshgrid(np.linspace(-0.02, 0.02, 41), np.linspace(-0.02, 0.02, 41)), -1
    ).reshape(-1, 2)
    tilt = 0.06 + 0.1 * xy[:, 0]  # a tilted rest surface, 6 cm away
    rest = RestDepth(np.column_stack([xy, tilt]))
    bump = -0.003 * np.exp(-(xy**2).sum(1) / (2 * 0.004**2))  # pulled 3 mm towards the camera
    pulled = np.column_stack([xy + 0.0002, tilt + 0.1 * 0.0002 + bump])  # and slid 0.2 mm
    change = rest.change_m(pulled)
    centre, rim = np.argmin((xy**2).sum(1)), np.argmax((xy**2).sum(1))
    assert change[centre] == pytest.approx(-0.003, abs=1e-4)
    assert abs(change[rim]) < 1e-4
    np.testing.assert_allclose(change, bump, atol=2e-4)
    four = rest.with_change(pulled)
    assert four.shape == (len(xy), 4) and four.dtype == np.float32
    with pytest.raises(EstimateError, match="rest cloud"):
        RestDepth(np.full((5, 3), np.nan))


def test_the_rest_depth_channel_reaches_the_network(clouds):
    torch.manual_seed(0)
    net = PointNetRegressor(conv_channels=(16, 32), head_channels=(16,), rest_depth=True).eval()
    net.set_normalization(
        torch.zeros(1), torch.ones(1), torch.zeros(4), torch.ones(4), depth_std=0.001
    )
    flat = torch.cat([clouds, torch.zeros(*clouds.shape[:2], 1)], dim=2)
    pulled = flat.clone()
    pulled[..., 3] = -0.002  # same shape, moved 2 mm against the rest surface
    with torch.no_grad():
        assert not torch.allclose(net(flat), net(pulled))
        assert float(net.depth_scale) == pytest.approx(0.001)
        again = PointNetRegressor(**net.hparams)
        again.load_state_dict(net.state_dict())
        torch.testing.assert_close(again.eval()(pulled), net(pulled))
