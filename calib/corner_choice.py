"""Each view's corners chosen by how well they fit the board: the refinement candidates of a
detection (:class:`vbfe.calib.board.Candidate`) are compared by their reprojection residual
after a per-view pose solve (``solvePnP``) with the camera's intrinsics, which come from a
calibration on the corners chosen so far (or are given, when fixed).

No single refinement suits every image (issue 40): on soft, noisy 1080p views the crossings of
the board's edge lines fit best, on small sharp corners sometimes an 11×11 or smaller window
does, and neighbouring views of one set may differ. The residual measures the corners against
the board's known geometry, so the choice needs no image model; but a pose absorbs a bias that
moves a view's corners as a whole (a scale), so only refinements free of such a bias on a
symmetric corner are compared: the sector detector's ``ACCURACY`` corners are not (their lower
residual on blurred boards came with f and B 0.1 % off the truth, see
:mod:`vbfe.calib.edge_lines`).
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.calib.board import BoardSpec, Candidate, Detection
from vbfe.calib.camera_model import CameraModel

log = logging.getLogger(__name__)

_ROUNDS = 2  # choose, recalibrate on the chosen corners, choose again
_MIN_CORNERS = 6  # fewer leave a view's pose and residual poorly determined
_MIN_VIEWS = 3  # fewer cannot calibrate the intrinsics the residuals need
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-7)


@dataclass(frozen=True)
class CornerChoice:
    """How one view's corners were made: the detector that found the board, the refinement
    kept (method and window), the board's edge width (10-90 %, px) and the kept corners'
    residual (RMS px of the per-view pose fit; NaN when there was nothing to compare)."""

    view: str
    camera: str
    finder: str
    method: str
    edge_width_px: float
    residual_px: float

    def row(self) -> list:
        """``[view, camera, finder, method, edge width, residual]`` for tables and files (None
        for an unknown number)."""
        return [
            self.view,
            self.camera,
            self.finder,
            self.method,
            _rounded(self.edge_width_px, 3),
            _rounded(self.residual_px, 4),
        ]


def _rounded(value: float, digits: int) -> float | None:
    return round(value, digits) if np.isfinite(value) else None


def _residual(obj: np.ndarray, corners: np.ndarray, K: np.ndarray, D: np.ndarray) -> float:
    img = corners.reshape(-1, 1, 2).astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, D)
    if not ok:
        return float("inf")
    projected, _ = cv2.projectPoints(obj, rvec, tvec, K, D)
    return float(np.sqrt(np.mean(np.sum((projected - img).reshape(-1, 2) ** 2, axis=1))))


def _intrinsics(
    obj: list[np.ndarray], chosen: list[np.ndarray], image_size: tuple[int, int], flags: int
) -> tuple[np.ndarray, np.ndarray] | None:
    try:
        _, K, D, _, _ = cv2.calibrateCamera(
            [o.astype(np.float32) for o in obj],
            [c.reshape(-1, 1, 2).astype(np.float32) for c in chosen],
            image_size,
            None,
            None,
            flags=flags,
            criteria=_CRITERIA,
        )
    except cv2.error:
        return None
    return K, D


def choose_corners(
    spec: BoardSpec,
    detections: list[Detection],
    names: list[str],
    image_size: tuple[int, int],
    camera: str,
    flags: int = 0,
    fixed: CameraModel | None = None,
) -> tuple[list[Detection], list[CornerChoice]]:
    """Each detection with the corners of its best-fitting candidate, and a record per
    detection of what was kept. Views without candidates (or too few corners) keep their
    corners; with fewer than :data:`_MIN_VIEWS` comparable views every view keeps its first
    candidate. ``flags`` go to ``calibrateCamera``; ``fixed`` intrinsics replace it."""
    object_points = spec.object_points()
    comparable = [
        k for k, d in enumerate(detections) if len(d.candidates) > 1 and len(d) >= _MIN_CORNERS
    ]
    picked: list[Candidate | None] = [d.candidates[0] if d.candidates else None for d in detections]
    residual = np.full(len(detections), np.nan)
    if len(comparable) >= _MIN_VIEWS or (fixed is not None and comparable):
        obj = [object_points[detections[k].ids].astype(np.float64) for k in comparable]
        for _ in range(_ROUNDS):
            if fixed is not None:
                K, D = fixed.K, fixed.D
            else:
                solved = _intrinsics(
                    obj,
                    [detections[k].corners_of(picked[k]) for k in comparable],
                    image_size,
                    flags,
                )
                if solved is None:
                    break
                K, D = solved
            for o, k in zip(obj, comparable, strict=True):
                fits = [_residual(o, c.corners, K, D) for c in detections[k].candidates]
                best = int(np.argmin(fits))
                picked[k], residual[k] = detections[k].candidates[best], fits[best]
            if fixed is not None:
                break
    chosen = [d if c is None else d.using(c) for d, c in zip(detections, picked, strict=True)]
    records = [
        CornerChoice(
            name,
            camera,
            d.finder or "given",
            c.label if c is not None else "given",
            d.edge_width_px,
            float(r),
        )
        for name, d, c, r in zip(names, detections, picked, residual, strict=True)
    ]
    for record in records:
        log.debug("%s %s: corners kept from %s", camera, record.view, record.method)
    methods = Counter(record.method for record in records)
    log.info("%s camera: corners chosen in %d views (%s)", camera, len(records), dict(methods))
    return chosen, records


def counts(choices: list[CornerChoice]) -> dict[str, dict[str, int]]:
    """Views per detector that found the board and per refinement kept."""
    return {
        "finder": dict(Counter(c.finder for c in choices)),
        "method": dict(Counter(c.method for c in choices)),
    }


def _counted(counted: dict[str, int]) -> str:
    return ", ".join(f"{name} {n}" for name, n in sorted(counted.items(), key=lambda i: -i[1]))


def summary_rows(choices: list[CornerChoice]) -> list[tuple[str, str]]:
    """(label, value) rows: views per detector, per refinement kept, the edge widths and the
    kept corners' residuals."""
    if not choices:
        return []
    counted = counts(choices)
    widths = np.array([c.edge_width_px for c in choices])
    residuals = np.array([c.residual_px for c in choices])
    rows = [
        ("views per detector", _counted(counted["finder"])),
        ("corners kept", _counted(counted["method"])),
    ]
    if np.isfinite(widths).any():
        rows.append(
            (
                "edge width (10-90 %)",
                f"{np.nanmin(widths):.2f} to {np.nanmax(widths):.2f} px "
                f"(median {np.nanmedian(widths):.2f})",
            )
        )
    if np.isfinite(residuals).any():
        rows.append(
            (
                "per-view corner fit",
                f"{np.nanmin(residuals):.3f} to {np.nanmax(residuals):.3f} px RMS",
            )
        )
    return rows


def from_rows(rows: list[list]) -> list[CornerChoice]:
    """The records :meth:`CornerChoice.row` wrote (e.g. into a calibration's info)."""
    return [
        CornerChoice(*row[:4], *(float("nan") if v is None else float(v) for v in row[4:6]))
        for row in rows
    ]
