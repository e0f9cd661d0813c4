"""Chessboard stereo sets on which vbfe's corners are measured against plain OpenCV (issue 40,
issue 45): OpenCV's own stereo sample (tests/data/opencv_stereo) as it is, shrunk and blurred,
and darkened as a dim analog endoscope records it (noise, JPEG)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

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
            assert ok
            eyes.append(cv2.imdecode(encoded, cv2.IMREAD_GRAYSCALE))
        out.append((eyes[0], eyes[1]))
    return out


SETS = {"sharp": sharp, "shrunk": shrunk, "dark": dark}


def write_pairs(folder: Path, pairs: Pairs) -> Path:
    """The pairs as leftNN.png / rightNN.png (the sample's naming, lossless)."""
    folder.mkdir(parents=True, exist_ok=True)
    for view, (left, right) in zip(VIEWS, pairs, strict=True):
        cv2.imwrite(str(folder / f"left{view}.png"), left)
        cv2.imwrite(str(folder / f"right{view}.png"), right)
    return folder
