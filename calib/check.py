"""Is the stored calibration still good? Its own sanity gates, then a comparison with a new
calibration and/or fresh views."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vbfe.acquire.image_size import size_mismatch
from vbfe.calib.board import BoardDetector, BoardSpec, Detection
from vbfe.calib.calibration import Calibration
from vbfe.calib.chessboard import is_clear, same_numbering
from vbfe.calib.gates import GateLimits, stereo_problems
from vbfe.calib.options import DEFAULTS
from vbfe.calib.stereo import StereoOptions
from vbfe.calib.views import ViewSet, check_sizes
from vbfe.common.errors import CalibrationError


def _mm(length_m: float | None) -> str:
    return "-" if length_m is None else f"{length_m * 1e3:.3f} mm"


@dataclass
class CheckResult:
    """Outcome of :func:`check_calibration`; ``passed`` is the go/no-go."""

    working_distance_m: float
    max_depth_error_m: float
    max_epipolar_px: float
    deltas: dict[str, float] = field(default_factory=dict)  # f_px, B_m, cx_px, cy_px
    depth_error_params_m: float | None = None  # from the parameter change
    depth_error_views_m: float | None = None  # from triangulating the fresh views' board
    board_scale: float | None = None  # measured / true board size with the stored calibration
    epipolar_rms_px: float | None = None
    views_used: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  # failed sanity gates: always NO-GO

    @property
    def depth_error_m(self) -> float:
        """The larger of the two depth error estimates at the working distance."""
        values = [v for v in (self.depth_error_params_m, self.depth_error_views_m) if v is not None]
        return max(values) if values else float("nan")

    def failures(self) -> list[str]:
        """What fails the check, each with its value, limit and remedy (empty: GO)."""
        out = list(self.problems)
        z_mm = self.working_distance_m * 1e3
        if not self.depth_error_m <= self.max_depth_error_m:
            out.append(
                f"depth error at {z_mm:.0f} mm {self.depth_error_m * 1e3:.3f} mm is above "
                f"the limit {self.max_depth_error_m * 1e3:.3f} mm (--max-depth-error-mm): "
                "the focal length or baseline has changed; recalibrate"
            )
        if self.epipolar_rms_px is not None and not self.epipolar_rms_px <= self.max_epipolar_px:
            out.append(
                f"epipolar RMS {self.epipolar_rms_px:.3f} px is above the limit "
                f"{self.max_epipolar_px:.3f} px (--max-epipolar-px): left and right rows "
                "no longer line up (the eyes have moved against each other); recalibrate"
            )
        return out

    @property
    def passed(self) -> bool:
        """No failed sanity gate, depth error within the threshold and, with views, epipolar
        error too."""
        return not self.failures()

    def rows(self) -> list[tuple[str, str]]:
        """(label, value) rows for display."""
        if self.problems:
            return [("refused", problem) for problem in self.problems] + [
                ("verdict", "NO-GO: the calibration fails its sanity gates; recalibrate")
            ]
        out = []
        if self.deltas:
            out += [
                ("Δf", f"{self.deltas['f_px']:+.3f} px"),
                ("ΔB", f"{self.deltas['B_m'] * 1e3:+.4f} mm"),
                ("Δcx, Δcy", f"{self.deltas['cx_px']:+.3f}, {self.deltas['cy_px']:+.3f} px"),
                ("depth error (parameters)", _mm(self.depth_error_params_m)),
            ]
        if self.epipolar_rms_px is not None:
            out += [
                ("views", ", ".join(self.views_used)),
                (
                    "epipolar RMS",
                    f"{self.epipolar_rms_px:.3f} px (limit {self.max_epipolar_px:.2f})",
                ),
                ("board scale", f"{self.board_scale:.5f}"),
                ("depth error (views)", _mm(self.depth_error_views_m)),
            ]
        failures = self.failures()
        out.append(
            (
                f"verdict at {self.working_distance_m * 1e3:.0f} mm",
                "NO-GO: " + "; ".join(failures)
                if failures
                else f"GO: depth error {self.depth_error_m * 1e3:.3f} mm, limit "
                f"{self.max_depth_error_m * 1e3:.3f} mm"
                + (
                    f"; epipolar RMS {self.epipolar_rms_px:.3f} px, limit "
                    f"{self.max_epipolar_px:.3f} px"
                    if self.epipolar_rms_px is not None
                    else ""
                ),
            )
        )
        return out


def triangulate_rectified(
    calibration: Calibration, left_px: np.ndarray, right_px: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """3-D points (n×3, m, rectified left frame, z = fB/d) of matched raw pixels, and the
    row differences (px) after rectification."""
    pl, pr = calibration.rectify_points(left_px, right_px)
    z = calibration.f * calibration.B / (pl[:, 0] - pr[:, 0])
    points = np.column_stack(
        [
            (pl[:, 0] - calibration.cx) * z / calibration.f,
            (pl[:, 1] - calibration.cy) * z / calibration.f,
            z,
        ]
    )
    return points, pr[:, 1] - pl[:, 1]


def board_scale(points: np.ndarray, board_points: np.ndarray) -> float:
    """Least-squares ratio of measured to true distances between all pairs of board corners."""
    i, j = np.triu_indices(len(points), k=1)
    measured = np.linalg.norm(points[i] - points[j], axis=1)
    true = np.linalg.norm(board_points[i] - board_points[j], axis=1)
    return float(measured @ true / (true @ true))


def check_calibration(
    stored: Calibration,
    new: Calibration | None = None,
    views: ViewSet | None = None,
    spec: BoardSpec | None = None,
    max_depth_error_m: float | None = None,
    max_epipolar_px: float | None = None,
    working_distance_m: float | None = None,
    min_corners: int = 12,
    limits: GateLimits | None = None,
) -> CheckResult:
    """Compare ``stored`` with a ``new`` calibration (parameter deltas) and/or fresh ``views`` of
    the board (epipolar error and board scale triangulated with ``stored``). A stored (or new)
    calibration failing the sanity gates (:mod:`vbfe.calib.gates`) is a NO-GO whatever it is
    compared with."""
    if new is None and views is None:
        raise CalibrationError("nothing to check against: give a new calibration or fresh views")
    z = working_distance_m or float(
        stored.info.get("working_distance_m", StereoOptions().working_distance_m)
    )
    result = CheckResult(
        z,
        max_depth_error_m or DEFAULTS.check_max_depth_error_mm / 1e3,
        max_epipolar_px or DEFAULTS.check_max_epipolar_px,
    )
    limits = limits or GateLimits()
    result.problems = [f"stored: {p}" for p in stereo_problems(stored, limits)]
    if new is not None:
        result.problems += [f"new: {p}" for p in stereo_problems(new, limits)]
    if result.problems:
        return result
    if new is not None:
        result.deltas = {
            "f_px": new.f - stored.f,
            "B_m": new.B - stored.B,
            "cx_px": new.cx - stored.cx,
            "cy_px": new.cy - stored.cy,
        }
        result.depth_error_params_m = z * abs(new.f * new.B / (stored.f * stored.B) - 1)
    if views is not None:
        if spec is None:
            raise CalibrationError("checking fresh views needs the board description")
        mismatch = size_mismatch(
            f"{views.source} has", check_sizes(views), "the stored calibration", stored.image_size
        )
        if mismatch:
            raise CalibrationError(mismatch)
        detector = BoardDetector(spec)
        board_points = spec.object_points()
        epi, scales = [], []
        for name, (left, right) in zip(views.names, views.pairs, strict=False):
            dl, dr = detector.detect(left), detector.detect(right)
            if spec.target == "chessboard" and len(dl) and len(dr):
                corners, _, contrast = same_numbering(dl.corners, dr.corners, spec.inner_corners)
                if not is_clear(contrast):
                    continue  # which corner is which in the right eye is ambiguous
                dr = Detection(dr.ids, corners)
            common, il, ir = np.intersect1d(dl.ids, dr.ids, return_indices=True)
            if len(common) < min_corners:
                continue
            points, dy = triangulate_rectified(stored, dl.corners[il], dr.corners[ir])
            epi.append(dy)
            scales.append(board_scale(points, board_points[common]))
            result.views_used.append(name)
        if not scales:
            raise CalibrationError(
                f"{views.source}: no view shows at least {min_corners} board "
                "corners in both eyes; check the board options and lighting"
            )
        all_epi = np.concatenate(epi)
        result.epipolar_rms_px = float(np.sqrt(np.mean(all_epi**2)))
        result.board_scale = float(np.median(scales))
        result.depth_error_views_m = z * abs(result.board_scale - 1)
    return result
