"""Chessboard stereo sets on which vbfe's corners are measured against plain OpenCV (issue 40,
issue 45): OpenCV's own stereo sample (tests/data/opencv_stereo) as it is, shrunk and blurred,
and darkened as a dim analog endoscope records it (noise, JPEG); and bench renders of a 1080p
endoscope with soft optics (known truth)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vbfe.drivers.sim.charuco_scene import (
    ChessboardPattern,
    random_board_poses,
    render_board_views,
)
from vbfe.drivers.sim.optics import Optics
from vbfe.drivers.sim.rig import StereoRig, default_rig

SAMPLE = Path(__file__).parent / "data" / "opencv_stereo"
VIEWS = [f"{i:02d}" for i in range(1, 15) if i != 10]  # stereo_calib.xml's list
INNER = (9, 6)
SQUARE_MM = 1.0
Pairs = list[tuple[np.ndarray, np.ndarray]]


def sharp() -> Pairs:
    """The 13 pairs as OpenCV ships them (grey, 640×480)."""
    return [
        tuple(  # type: ignore[misc]
            cv2.imread(str(SAMPLE / f"{eye}{view}.jpg"), cv2.IMREAD_GRAYSCALE)
            for eye in ("left", "right")
        )
        for view in VIEWS
    ]


def shrunk(scale: float = 0.65, blur_sigma_px: float = 1.0) -> Pairs:
    """The pairs resized by ``scale`` (area averaging) and blurred by a Gaussian of
    ``blur_sigma_px``: small, soft corners (spacing 11-24 px)."""
    return [
        tuple(  # type: ignore[misc]
            cv2.GaussianBlur(
                cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA),
                (0, 0),
                blur_sigma_px,
            )
            for g in pair
        )
        for pair in sharp()
    ]


def dark(mean_grey: float = 20.0, noise_sigma: float = 3.0, jpeg_quality: int = 75) -> Pairs:
    """The pairs scaled to a mean grey of ``mean_grey``, with Gaussian sensor noise and JPEG
    compression (a dim SD endoscope channel; seeded)."""
    rng = np.random.default_rng(45)
    out = []
    for pair in sharp():
        eyes = []
        for g in pair:
            dim = g.astype(np.float32) * (mean_grey / float(g.mean()))
            dim += rng.normal(0.0, noise_sigma, g.shape).astype(np.float32)
            ok, encoded = cv2.imencode(
                ".jpg",
                np.clip(np.rint(dim), 0, 255).astype(np.uint8),
                [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality],
            )
            decoded = cv2.imdecode(encoded, cv2.IMREAD_GRAYSCALE)
            assert ok and decoded is not None
            eyes.append(decoded)
        out.append((eyes[0], eyes[1]))
    return out


SETS = {"sharp": sharp, "shrunk": shrunk, "dark": dark}


def write_pairs(folder: Path, pairs: Pairs, names: list[str] = VIEWS) -> Path:
    """The pairs as leftNN.png / rightNN.png (the sample's naming, lossless)."""
    folder.mkdir(parents=True, exist_ok=True)
    for view, (left, right) in zip(names, pairs, strict=True):
        cv2.imwrite(str(folder / f"left{view}.png"), left)
        cv2.imwrite(str(folder / f"right{view}.png"), right)
    return folder


# A 1080p stereo endoscope seen through soft optics: a chessboard of 31×19 inner corners, 1 mm
# squares (large enough to span a good part of the view) at
# 55-85 mm, i.e. corners 16-25 px apart, as on the real laparoscope set of issue 40.
ENDOSCOPE_INNER = (31, 19)
ENDOSCOPE_SQUARE_MM = 1.0
ENDOSCOPE_OPTICS = Optics(
    defocus_px=2.0, vignetting=0.35, exposure=0.8, shot_noise=0.6, noise_sigma=2.0, jpeg_quality=80
)


def endoscope_rig() -> StereoRig:
    """The bench's endoscope at 1920×1080 with lens distortion and a 4 mm baseline."""
    return default_rig(1920, 1080, baseline_m=0.004, distortion=True)


def endoscope(n: int = 10, seed: int = 0, supersample: int = 2) -> Pairs:
    """``n`` pairs of the chessboard at random poses, rendered through
    :data:`ENDOSCOPE_OPTICS` (grey)."""
    rng = np.random.default_rng(seed)
    rig = endoscope_rig()
    pattern = ChessboardPattern(ENDOSCOPE_INNER, ENDOSCOPE_SQUARE_MM * 1e-3)
    poses = random_board_poses(
        n,
        rng,
        distance_m=(0.055, 0.085),
        max_tilt_deg=45.0,
        rig=rig,
        board=pattern,
        min_visible=1.0,
    )
    views = render_board_views(
        rig, pattern, poses, optics=ENDOSCOPE_OPTICS, supersample=supersample, rng=rng
    )
    return [(left[..., 0].copy(), right[..., 0].copy()) for left, right in views]
