"""The modified PointNet force regressor of the paper (section III-B).

Each cloud is centred on its (weighted) centroid and divided by D_max, its largest pairwise
point distance, so it fits in the unit sphere. D_max is computed exactly: ``torch.cdist`` over
the points that can be diameter ends (O(N²) in the worst case, the rim of a patch in
practice), see ``diameter``. A shared per-point MLP (1×1
``Conv1d`` + batch norm + ELU), global max pooling and a fully connected head (batch norm, ELU,
dropout) end in a linear output in newtons.

Normalisation removes the cloud's position and size, which on a pulled tissue carry much of the
force signal; with ``global_features=True`` the removed centroid (x, y, z) and D_max are fed to
the head as four extra, standardised inputs. With ``rest_depth=True`` (vbfe's modification,
see ``rest_depth.py``) every point carries a fourth input, its depth change against the
session's rest cloud, divided by its training standard deviation: clouds are then B×N×4.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

ARCHITECTURE = "pointnet-regressor"
ARCHITECTURE_VERSION = 1
N_GLOBAL_FEATURES = 4  # centroid x, y, z and D_max, metres


def weighted_centroid(points: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
    """Centroid (B×3) of clouds (B×N×3) with per-point weights (B×N, default 1)."""
    if weights is None:
        return points.mean(dim=1)
    w = weights.unsqueeze(-1)
    return (points * w).sum(dim=1) / w.sum(dim=1)


def diameter(points: torch.Tensor) -> torch.Tensor:
    """Exact largest pairwise distance D_max (B) of clouds (B×N×3).

    Both ends of a diameter lie at least ``D_lower - r_max`` from the mean (``r_max``: farthest
    point from the mean, ``D_lower``: farthest point from that one, a lower bound of D_max), so
    only those points are compared pairwise; the result is exact, and a flat tissue patch
    leaves only its rim to compare.
    """
    with torch.no_grad():
        out = []
        for cloud in points:
            radius = (cloud - cloud.mean(dim=0)).norm(dim=1)
            farthest = cloud[radius.argmax()]
            lower = (cloud - farthest).norm(dim=1).max()
            rim = cloud[radius >= lower - radius.max()]
            out.append(torch.cdist(rim, rim).max())
        return torch.stack(out)


def normalize_clouds(
    points: torch.Tensor, weights: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Centre clouds (B×N×3) on their weighted centroid and scale by D_max into the unit sphere.

    Returns (normalised clouds, removed features B×4 = centroid x, y, z and D_max in metres);
    a cloud of identical points has D_max 0 and is only centred.
    """
    centroid = weighted_centroid(points, weights)
    d_max = diameter(points)
    scale = torch.where(d_max > 0, d_max, torch.ones_like(d_max))
    normalized = (points - centroid.unsqueeze(1)) / scale.view(-1, 1, 1)
    return normalized, torch.cat([centroid, d_max.unsqueeze(1)], dim=1)


def _shared_mlp(channels: Sequence[int], n_in: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for c_in, c_out in zip([n_in, *channels[:-1]], channels, strict=False):
        layers += [nn.Conv1d(c_in, c_out, kernel_size=1), nn.BatchNorm1d(c_out), nn.ELU()]
    return nn.Sequential(*layers)


def shared_mlp_pooled(mlp: nn.Sequential, points: torch.Tensor) -> torch.Tensor:
    """The shared per-point MLP on clouds B×N×C, max-pooled over the points (B×C_out).

    Points last: every 1×1 ``Conv1d`` is one matrix product over all B·N points with the
    convolution's own weights, batch norm sees (B·N)×C (the same per-channel statistics as on
    B×C×N) and ELU works in place: the same network (and state dict) as ``mlp`` applied to
    B×C×N, faster on a CPU (no transposes, one GEMM per layer, one tensor less per ELU). The
    last block (convolution, batch norm, ELU) is pooled first: see :func:`_pooled_block`.
    """
    b, n = points.shape[:2]
    x = points.reshape(b * n, -1)
    *body, conv, norm, elu = mlp
    for layer in body:
        if isinstance(layer, nn.Conv1d):
            x = F.linear(x, layer.weight.squeeze(-1), layer.bias)
        elif isinstance(layer, nn.ELU):
            x = F.elu(x, layer.alpha, inplace=True)
        else:
            x = layer(x)
    assert isinstance(conv, nn.Conv1d) and isinstance(norm, nn.BatchNorm1d)
    assert isinstance(elu, nn.ELU)
    return _pooled_block(conv, norm, elu.alpha, x.reshape(b, n, -1))


class _Covariance(torch.autograd.Function):
    """``centred.T @ centred / M`` of centred M×C rows, its gradient in one matrix product
    (``centred @ (G + G.T) / M``; autograd's product rule takes two and a transpose of M×C)."""

    @staticmethod
    def forward(ctx: torch.autograd.function.FunctionCtx, centred: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(centred)
        return centred.T @ centred / len(centred)

    @staticmethod
    def backward(ctx: torch.autograd.function.FunctionCtx, grad: torch.Tensor) -> torch.Tensor:
        (centred,) = ctx.saved_tensors  # type: ignore[attr-defined]
        return centred @ ((grad + grad.T) / len(centred))


def _batch_statistics(
    norm: nn.BatchNorm1d, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and (biased) variance over the points of ``x @ weight.T + bias`` (x: M×C_in),
    from the mean and covariance of ``x`` (C_in² numbers, not M×C_out), batch norm's running
    statistics updated as ``nn.BatchNorm1d`` updates them."""
    mean_in = x.mean(0)
    centred = x - mean_in
    mean = weight @ mean_in + (bias if bias is not None else 0.0)
    var = ((weight @ _Covariance.apply(centred)) * weight).sum(1)
    if norm.training and norm.track_running_stats and norm.running_mean is not None:
        assert norm.running_var is not None and norm.num_batches_tracked is not None
        with torch.no_grad():
            norm.num_batches_tracked.add_(1)
            factor = (
                1.0 / float(norm.num_batches_tracked) if norm.momentum is None else norm.momentum
            )
            norm.running_mean.lerp_(mean, factor)
            norm.running_var.lerp_(var * len(x) / max(len(x) - 1, 1), factor)
    return mean, var


def _pooled_block(
    conv: nn.Conv1d, norm: nn.BatchNorm1d, alpha: float, x: torch.Tensor
) -> torch.Tensor:
    """``max over points of ELU(norm(conv(x)))`` for x B×N×C_in, the same as computing it
    point by point (forward, gradients and batch norm's statistics): batch norm is an affine
    map per channel and ELU rises, so the maximum comes from the point where the convolution's
    output is largest (smallest where the batch norm's scale is negative). The convolution over
    all points runs once without gradients to find those points; batch norm's statistics come
    from the input's covariance; only the chosen points' outputs (B×C_out) carry gradients.
    On the paper's network this skips batch norm and ELU on B·N×1024 values and the backward
    matrix products of the widest layer."""
    b, n, c_in = x.shape
    weight, bias = conv.weight.squeeze(-1), conv.bias
    if norm.training or norm.running_mean is None:
        mean, var = _batch_statistics(norm, x.reshape(b * n, c_in), weight, bias)
    else:
        assert norm.running_var is not None
        mean, var = norm.running_mean, norm.running_var
    scale = torch.rsqrt(var + norm.eps)
    if norm.weight is not None:
        scale = scale * norm.weight
    shift = -mean * scale + (norm.bias if norm.bias is not None else 0.0)
    with torch.no_grad():  # C_out×N per cloud without the bias (the same per point): each
        # cloud's product is searched while it is in the cache (a paper-sized step 0.89x); a
        # falling channel's weights negated (exactly the negated product): its smallest point
        # is the largest; ``max`` gives argmax's index (the first) in a third of its time
        signed = torch.where((scale < 0).unsqueeze(1), -weight, weight)
        chosen = torch.stack([signed.mm(cloud.T).max(dim=-1).indices for cloud in x])  # B×C_out
        chosen += torch.arange(b).unsqueeze(1) * n  # rows of x flattened to B·N×C_in
    # the chosen points' rows (B×C_out×C_in): index_select's forward and backward copy whole
    # rows (gather's, on an expanded index, element by element: 2.4x the time, same values)
    rows = x.reshape(b * n, c_in).index_select(0, chosen.reshape(-1)).reshape(b, -1, c_in)
    value = (rows * weight).sum(-1) + (bias if bias is not None else 0.0)
    return F.elu(value * scale + shift, alpha)


def _head(n_in: int, channels: Sequence[int], dropout: float, n_outputs: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for c_in, c_out in zip([n_in, *channels[:-1]], channels, strict=False):
        layers += [nn.Linear(c_in, c_out), nn.BatchNorm1d(c_out), nn.ELU(), nn.Dropout(dropout)]
    layers.append(nn.Linear(channels[-1] if channels else n_in, n_outputs))
    return nn.Sequential(*layers)


class PointNetRegressor(nn.Module):
    """Point clouds (B×N×3, or B×N×4 with the rest depth change; metres, any point order) →
    force (B×n_outputs, newtons)."""

    # buffers (register_buffer), saved with the weights
    target_mean: torch.Tensor
    target_std: torch.Tensor
    feature_mean: torch.Tensor
    feature_std: torch.Tensor
    depth_scale: torch.Tensor

    def __init__(
        self,
        n_outputs: int = 1,
        conv_channels: Sequence[int] = (64, 128, 1024),
        head_channels: Sequence[int] = (512, 256),
        dropout: float = 0.3,
        global_features: bool = True,
        rest_depth: bool = False,
    ) -> None:
        super().__init__()
        self.hparams = {
            "n_outputs": n_outputs,
            "conv_channels": list(conv_channels),
            "head_channels": list(head_channels),
            "dropout": dropout,
            "global_features": global_features,
            "rest_depth": rest_depth,
        }
        self.global_features = global_features
        self.rest_depth = rest_depth
        self.features = _shared_mlp(conv_channels, 4 if rest_depth else 3)
        self.embedding_size = conv_channels[-1] + (N_GLOBAL_FEATURES if global_features else 0)
        self.head = _head(self.embedding_size, head_channels, dropout, n_outputs)
        self.register_buffer("target_mean", torch.zeros(n_outputs))
        self.register_buffer("target_std", torch.ones(n_outputs))
        self.register_buffer("feature_mean", torch.zeros(N_GLOBAL_FEATURES))
        self.register_buffer("feature_std", torch.ones(N_GLOBAL_FEATURES))
        if rest_depth:
            self.register_buffer("depth_scale", torch.ones(1))

    def set_normalization(
        self,
        target_mean: torch.Tensor,
        target_std: torch.Tensor,
        feature_mean: torch.Tensor,
        feature_std: torch.Tensor,
        depth_std: float = 1.0,
    ) -> None:
        """Set the force scaling, the global-feature standardisation and (with
        ``rest_depth``) the depth-change scale, all from training data."""
        self.target_mean.copy_(target_mean)
        self.target_std.copy_(torch.clamp(target_std, min=1e-6))
        self.feature_mean.copy_(feature_mean)
        self.feature_std.copy_(torch.clamp(feature_std, min=1e-9))
        if self.rest_depth:
            self.depth_scale.fill_(max(depth_std, 1e-9))

    @staticmethod
    def cloud_features(points: torch.Tensor) -> torch.Tensor:
        """The global features removed by normalisation: centroid and D_max (B×4, metres)."""
        return normalize_clouds(points[..., :3])[1]

    def embed(self, points: torch.Tensor) -> torch.Tensor:
        """Per-cloud embedding (B×embedding_size): pooled point features + global features."""
        normalized, features = normalize_clouds(points[..., :3])
        if self.rest_depth:
            normalized = torch.cat([normalized, points[..., 3:4] / self.depth_scale], dim=-1)
        pooled = shared_mlp_pooled(self.features, normalized)
        if self.global_features:
            pooled = torch.cat([pooled, (features - self.feature_mean) / self.feature_std], dim=1)
        return pooled

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        return self.head(self.embed(points)) * self.target_std + self.target_mean


class TemporalPointNet(PointNetRegressor):
    """The PointNet encoder over a causal window: rest cloud + the last k clouds → force.

    Input ``B × (1 + k) × N × C`` (C = 3, or 4 with ``rest_depth``): the session's rest frame
    first, then the window oldest to newest. Every cloud is embedded by the shared encoder.
    The force is the single-frame head on the newest cloud (as in ``PointNetRegressor``, whose
    trained weights it can start from) plus a motion correction: a second head on each window
    cloud's embedding minus the rest cloud's, so it can read how the surface has moved and how it is
    moving (a relaxing tissue at constant shape). The correction's output layer starts at zero.
    """

    def __init__(
        self,
        n_outputs: int = 1,
        n_frames: int = 4,
        conv_channels: Sequence[int] = (64, 128, 1024),
        head_channels: Sequence[int] = (512, 256),
        dropout: float = 0.3,
        global_features: bool = True,
        rest_depth: bool = False,
    ) -> None:
        super().__init__(
            n_outputs, conv_channels, head_channels, dropout, global_features, rest_depth
        )
        self.hparams["n_frames"] = n_frames
        self.n_frames = n_frames
        self.motion_head = _head(self.embedding_size * n_frames, head_channels, dropout, n_outputs)
        last = self.motion_head[-1]
        assert isinstance(last, nn.Linear)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)

    @staticmethod
    def cloud_features(points: torch.Tensor) -> torch.Tensor:
        """Global features of every cloud of the windows (B·(1+k)×4, metres)."""
        return normalize_clouds(points.reshape(-1, *points.shape[-2:])[..., :3])[1]

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        b, w = points.shape[:2]
        emb = self.embed(points.reshape(b * w, *points.shape[2:])).reshape(b, w, -1)
        motion = self.motion_head((emb[:, 1:] - emb[:, :1]).reshape(b, -1))
        return (self.head(emb[:, -1]) + motion) * self.target_std + self.target_mean
