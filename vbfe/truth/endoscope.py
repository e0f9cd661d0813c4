"""Board views of an SD analog stereo endoscope on the simulated bench, written as another
lab's image folder (``left/leftNN.png`` + ``right/rightNN.png``), with the bench's true rig.

Two SD analog channels digitised at 640×480: non-square pixels (fx / fy = 1.1), the eyes'
principal points 90 px apart in x (the digitiser samples the two channels' lines from
different starts), a 6 mm baseline, mild lens distortion; the images dim (mean grey about 40,
white paper at about 80) and noisy (σ 2 grey levels), as an endoscope's light at the edge of its
range gives them.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vbfe.drivers.sim.bench import SimBench
from vbfe.drivers.sim.board_scene import board_target
from vbfe.drivers.sim.charuco_scene import random_board_poses, render_board_views
from vbfe.drivers.sim.rig import StereoRig

# the [bench] keys of the endoscope (the sim driver's configuration)
SD_ENDOSCOPE: dict[str, Any] = {
    "width": 640,
    "height": 480,
    "baseline_m": 0.006,
    "pixel_aspect": 1.1,
    "principal_offsets_px": [[-45.0, 0.0], [45.0, 0.0]],
    "distortion": True,
}
DIM_GAIN = 0.3  # white paper at about 80 grey levels, black at the offset
DIM_OFFSET = 4.0
NOISE_SIGMA = 2.0
DISTANCE_M = (0.035, 0.07)


def sd_endoscope_rig() -> StereoRig:
    """The endoscope's true rig, as the bench builds it from :data:`SD_ENDOSCOPE`."""
    return SimBench.from_config(dict(SD_ENDOSCOPE)).rig


def barrel_endoscope_rig() -> StereoRig:
    """The SD endoscope as the labs of issue 56 measured theirs: fx / fy = 1.05, principal
    points 85 px apart in x, barrel distortion k1 = -0.3, the eyes turned 0.7° apart."""
    from vbfe.drivers.sim.rig import pinhole

    rig = sd_endoscope_rig()
    left = pinhole(640, 480, 70.0, (-0.3, 0.08, 0.0, 0.0, 0.0), (-42.0, 3.0), 1.05)
    right = pinhole(640, 480, 70.0, (-0.29, 0.07, 0.0, 0.0, 0.0), (43.0, -2.0), 1.05)
    axis = np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1])
    R = cv2.Rodrigues(np.radians(0.7) * axis)[0]
    return dataclasses.replace(rig, left=left, right=right, R=R)


def write_sd_endoscope_views(
    folder: str | Path,
    inner_corners: tuple[int, int],
    square_mm: float,
    n_views: int,
    seed: int = 0,
    swap_eyes: bool = False,
    rig: StereoRig | None = None,
) -> StereoRig:
    """Render ``n_views`` dim, noisy chessboard views (``inner_corners``, ``square_mm``) at
    random poses of ``rig`` (default :func:`sd_endoscope_rig`) into ``folder/left/leftNN.png``
    + ``folder/right/rightNN.png`` (with ``swap_eyes`` the files' eye labels are reversed);
    returns the true rig."""
    rig = rig or sd_endoscope_rig()
    nx, ny = inner_corners
    target = board_target("chessboard", nx + 1, ny + 1, square_mm, 0.0, "", False)
    rng = np.random.default_rng(seed)
    poses = random_board_poses(n_views, rng, distance_m=DISTANCE_M, rig=rig, board=target)
    folder = Path(folder)
    for eye in ("left", "right"):
        (folder / eye).mkdir(parents=True, exist_ok=True)
    for i, pair in enumerate(render_board_views(rig, target, poses, rng=rng)):
        for eye, image in zip(("left", "right"), pair[::-1] if swap_eyes else pair, strict=True):
            dim = image.astype(np.float32) * DIM_GAIN + DIM_OFFSET
            dim += rng.normal(0.0, NOISE_SIGMA, dim.shape[:2])[..., None].astype(np.float32)
            out = np.clip(np.rint(dim), 0, 255).astype(np.uint8)
            cv2.imwrite(str(folder / eye / f"{eye}{i + 1:02d}.png"), out)
    return rig
