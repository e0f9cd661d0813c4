"""From a raw cloud to what every force estimator reads, the same in training and live.

A run (a session, or ``vbfe live``) starts at rest: its first usable cloud is the reference
(``FramePreparer``). Every cloud is then cropped to the region of interest and turned into
``FrameFeatures``: a pool of points (with their depth change against the rest cloud when the
PointNet uses it, ``rest_depth.py``), the peak surface displacement (``displacement.py``), the
depth-change image (``depth_image.py``) and, when the clouds carry the colours of a textured
surface, the peak 3D displacement tracked in that texture (``texture_motion.py``, on the whole
cloud, not only the region of interest).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vbfe.common.errors import EstimateError
from vbfe.estimate.cell_passes import finite_rows
from vbfe.estimate.depth_image import DepthChangeImage
from vbfe.estimate.displacement import DisplacementGrid
from vbfe.estimate.rest_depth import RestDepth
from vbfe.estimate.texture_motion import TextureMotion
from vbfe.estimate.train_config import TrainConfig

MIN_FRAME_POINTS = 8


def crop_roi(points: np.ndarray, config: TrainConfig) -> np.ndarray:
    """The finite points of a cloud inside the configured region of interest."""
    points = finite_rows(np.ascontiguousarray(points).reshape(-1, 3))
    if config.roi == "radius" and len(points):
        centre = np.median(points, axis=0)
        points = points[np.linalg.norm(points - centre, axis=1) <= config.roi_radius_m]
    elif config.roi == "box":
        box = np.asarray(config.roi_box_m, dtype=np.float64)
        points = points[np.all((points >= box[:3]) & (points <= box[3:]), axis=1)]
    return points


def sample_points(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points: without replacement when the cloud has enough, else with replacement."""
    index = rng.choice(len(points), size=n, replace=len(points) < n)
    return points[index]


def force_target(forces_n: np.ndarray, target: str) -> np.ndarray:
    """Regression target (frames × outputs), newtons: |F|, the three axes, or one signed axis."""
    forces_n = np.asarray(forces_n, dtype=np.float64).reshape(-1, 3)
    if target == "magnitude":
        return np.linalg.norm(forces_n, axis=1, keepdims=True)
    if target == "xyz":
        return forces_n
    sign = -1.0 if target.startswith("-") else 1.0
    return sign * forces_n[:, "xyz".index(target[-1])][:, None]


def physical_estimate(predicted_n: np.ndarray, target: str) -> np.ndarray:
    """An estimator's force as a physical one: a magnitude below 0 N is impossible and reads 0
    (every method's estimate passes here, in training, evaluation and ``vbfe live``)."""
    return np.maximum(predicted_n, 0.0) if target == "magnitude" else predicted_n


def target_label(target: str) -> str:
    """Axis label of a target: ``|F| (N)``, ``F (N)`` for three axes, ``Fx (N)``, ``−Fz (N)``."""
    if target == "magnitude":
        return "|F| (N)"
    if target == "xyz":
        return "|F| of F = (Fx, Fy, Fz) (N)"
    return ("−" if target.startswith("-") else "") + f"F{target[-1]} (N)"


@dataclass
class FrameFeatures:
    """What the estimators read from one cloud."""

    pool: np.ndarray  # pool × 3 (4 with the rest depth change), float32, metres
    displacement_m: float  # peak surface displacement vs the rest cloud (NaN: none seen)
    image_sum: np.ndarray  # cells × cells: summed depth change (m) of the points in each cell
    image_count: np.ndarray  # cells × cells: points per cell
    texture_displacement_m: float = float("nan")  # peak 3D displacement in the texture (NaN: none)


class FramePreparer:
    """The features of every cloud of one run, measured against its rest (first usable) cloud."""

    def __init__(
        self,
        rest_points: np.ndarray,
        config: TrainConfig,
        rest_colors: np.ndarray | None = None,
        texture: bool = True,
    ) -> None:
        """``rest_colors``: the rest cloud's colours (N×3); with ``texture`` the texture is
        tracked when they show one (``texture_reason`` says why not otherwise)."""
        rest = crop_roi(rest_points, config)
        if len(rest) < MIN_FRAME_POINTS:
            raise EstimateError(
                f"the rest cloud has {len(rest)} points inside the region of "
                "interest; start from a frame where the tissue is seen at rest"
            )
        self.config = config
        self._grid = DisplacementGrid(rest)
        self._image = DepthChangeImage(rest, config.image_cells)
        self._rest = RestDepth(rest) if config.rest_depth else None
        self.texture: TextureMotion | None = None
        self.texture_reason = "texture tracking was not asked for"
        if texture:
            self.texture, self.texture_reason = TextureMotion.from_rest(rest_points, rest_colors)

    def cropped(self, points: np.ndarray) -> np.ndarray | None:
        """The cloud's points inside the ROI, or ``None`` when too few to use."""
        cropped = crop_roi(points, self.config)
        return cropped if len(cropped) >= MIN_FRAME_POINTS else None

    def features(
        self,
        cropped: np.ndarray,
        pool_size: int,
        rng: np.random.Generator,
        points: np.ndarray | None = None,
        colors: np.ndarray | None = None,
    ) -> FrameFeatures:
        """Features of a cropped cloud (from ``cropped``) with a pool of ``pool_size`` points;
        the texture displacement from the whole cloud ``points`` and its ``colors``."""
        pool = sample_points(cropped, pool_size, rng)
        total, count = self._image.sums_counts(cropped)
        texture = (
            self.texture.peak_displacement_m(points, colors)
            if self.texture is not None and points is not None
            else float("nan")
        )
        return FrameFeatures(
            pool=self._pool(pool),
            displacement_m=self._grid.peak_displacement_m(cropped),
            image_sum=total,
            image_count=count,
            texture_displacement_m=texture,
        )

    def pool_features(self, pool: np.ndarray) -> FrameFeatures:
        """Features holding only a drawn point pool (a network reads nothing else): no
        displacement, an empty depth-change image."""
        cells = (self.config.image_cells,) * 2
        return FrameFeatures(
            pool=self._pool(pool),
            displacement_m=float("nan"),
            image_sum=np.zeros(cells, np.float32),
            image_count=np.zeros(cells, np.float32),
        )

    def texture_features(self, points: np.ndarray, colors: np.ndarray | None) -> FrameFeatures:
        """Features holding only the texture displacement of the whole cloud ``points`` and
        its ``colors`` (an estimator on the texture alone reads nothing else): an empty pool,
        no surface displacement, an empty depth-change image; NaN without texture tracking."""
        cells = (self.config.image_cells,) * 2
        return FrameFeatures(
            pool=np.zeros((0, 4 if self._rest else 3), np.float32),
            displacement_m=float("nan"),
            image_sum=np.zeros(cells, np.float32),
            image_count=np.zeros(cells, np.float32),
            texture_displacement_m=(
                self.texture.peak_displacement_m(points, colors)
                if self.texture is not None
                else float("nan")
            ),
        )

    def _pool(self, pool: np.ndarray) -> np.ndarray:
        """The pool as the networks read it (with the rest depth change when configured)."""
        return self._rest.with_change(pool) if self._rest else pool.astype(np.float32)
