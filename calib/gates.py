"""Sanity gates: physically impossible or unusable calibrations are refused, not written.

A stereo calibration is refused when its baseline is not finite, negative (eyes swapped),
below a minimum or far from the rig's nominal baseline (when one is stated), when a rectified
principal point lies outside the image, when rectification keeps less than a fraction of the
image, or when its RMS reprojection error is above a limit. ``calibrate stereo`` raises on
these before writing; ``calibrate check`` says NO-GO for such a file. Every gate's outcome
(measured value, limit, verdict) is a :class:`Gate` row for the report.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.calib.options import CalibOptions, calib_field
from vbfe.calib.rectify import (
    ALPHAS,
    rectified_fractions,
    stereo_rectify,
    usable,
    worst_fraction,
)

log = logging.getLogger(__name__)

PASS, FAIL, UNCHECKED = "pass", "FAIL", "not checked"


@dataclass
class GateLimits(CalibOptions):
    """Limits of the sanity gates (defaults: the ``[calib]`` table)."""

    min_baseline_m: float = calib_field("min_baseline_mm", 1e-3)
    nominal_baseline_m: float = calib_field("nominal_baseline_mm", 1e-3)  # 0: not checked
    baseline_tolerance: float = calib_field("baseline_tolerance")  # of the nominal baseline
    max_rms_px: float = calib_field("max_rms_px")
    min_rectified_fraction: float = calib_field("min_rectified_fraction")


@dataclass
class Gate:
    """One gate's outcome: the measured value, the limit (with the option that sets it), the
    verdict (:data:`PASS`, :data:`FAIL` or :data:`UNCHECKED`) and, when it fails, why and what
    to do."""

    name: str
    measured: str
    limit: str
    verdict: str
    problem: str | None = None

    def row(self) -> list[str]:
        """[name, measured, limit, verdict] (the report's and the calibration file's row)."""
        return [self.name, self.measured, self.limit, self.verdict]


def _baseline_gates(cal: Calibration, limits: GateLimits) -> list[Gate]:
    B, T = cal.B, float(np.linalg.norm(cal.T))
    measured = f"{B * 1e3:.4f} mm"
    limit = f"> {limits.min_baseline_m * 1e3:g} mm (--min-baseline-mm)"
    if not np.isfinite(B) or not np.isfinite(T):
        gate = Gate("baseline", "not finite", limit, FAIL, "baseline is not a finite number")
    elif min(abs(B), T) < limits.min_baseline_m:
        gate = Gate(
            "baseline",
            measured,
            limit,
            FAIL,
            f"baseline {abs(min(B, T, key=abs)) * 1e3:.4f} mm is below the minimum "
            f"{limits.min_baseline_m * 1e3:g} mm (--min-baseline-mm): the left "
            "and right images look like one camera's; check the eyes are two "
            "cameras, and that --square-mm is the board's square in mm",
        )
    elif B < 0:
        gate = Gate(
            "baseline",
            measured,
            "> 0 mm (left eye left of the right one)",
            FAIL,
            f"baseline {B * 1e3:.4f} mm is negative (limit: above 0): the right eye's "
            "images come from the camera left of the left eye's, so the files' eye labels "
            "are reversed with respect to the geometry; exchange the eyes' files "
            "(left <-> right) or give --swap-eyes",
        )
    else:
        gate = Gate("baseline", measured, limit, PASS)
    nominal = limits.nominal_baseline_m
    if nominal <= 0 or gate.verdict == FAIL:
        return [
            gate,
            Gate(
                "nominal baseline",
                measured,
                "none stated (--nominal-baseline-mm)",
                UNCHECKED,
            ),
        ]
    off = abs(B / nominal - 1)
    limit = (
        f"{nominal * 1e3:g} mm ± {limits.baseline_tolerance * 100:g} % "
        "(--nominal-baseline-mm, --baseline-tolerance)"
    )
    problem = None
    if off > limits.baseline_tolerance:
        problem = (
            f"baseline {B * 1e3:.4f} mm is {off * 100:.1f} % from the rig's nominal "
            f"{nominal * 1e3:g} mm (limit {limits.baseline_tolerance * 100:g} %); if the "
            "rig's baseline is not that, give it with --nominal-baseline-mm (0 = not "
            "checked) or widen --baseline-tolerance"
        )
    return [gate, Gate("nominal baseline", measured, limit, FAIL if problem else PASS, problem)]


_SUPPORTED = 0.05  # a cause is named when leaving it out keeps this much more of the image


def rectification_cause(cal: Calibration, min_fraction: float) -> str:
    """What crops the rectified images, measured: the share of the image rectification keeps
    (the smaller of valid and kept, both eyes) as solved and, at the best free scaling, without
    each candidate cause (zero disparity with the principal-point offset between the eyes, the
    distortion, the rotation between the eyes). Only a cause whose removal keeps
    :data:`_SUPPORTED` more is named, and only remedies whose recomputed share reaches
    ``min_fraction`` are offered (also for a cause below that), each with the options that
    give it."""
    size = cal.image_size
    alpha = float(cal.info.get("rectify_alpha", 0.0))
    zero = abs(cal.doffs) < 1e-6
    angle = math.degrees(float(np.linalg.norm(cv2.Rodrigues(cal.R)[0])))
    dx, dy = cal.K2[0, 2] - cal.K1[0, 2], cal.K2[1, 2] - cal.K1[1, 2]

    def kept(
        D1: np.ndarray, D2: np.ndarray, zero_disparity: bool, R: np.ndarray, a: float
    ) -> float:
        rect = stereo_rectify(cal.K1, D1, cal.K2, D2, size, R, cal.T, a, zero_disparity)
        return worst_fraction(cal.K1, D1, cal.K2, D2, rect, size) if usable(rect) else 0.0

    def best(
        D1: np.ndarray, D2: np.ndarray, zero_disparity: bool, R: np.ndarray
    ) -> tuple[float, float]:
        shares = {a: kept(D1, D2, zero_disparity, R, a) for a in ALPHAS}
        a = max(shares, key=lambda k: shares[k])
        return shares[a], a

    def options(zero_disparity: bool, a: float, fix_k3: bool = False) -> str:
        said = [f"--rectify-alpha {a:g}"] if a != alpha else []
        if zero_disparity != zero:
            said.insert(0, f"--zero-disparity {'on' if zero_disparity else 'off'}")
        return " ".join((["--fix-k3"] if fix_k3 else []) + said)

    solved = kept(cal.D1, cal.D2, zero, cal.R, alpha)
    no_k3 = [np.where(np.arange(len(D)) == 4, 0.0, D) for D in (cal.D1, cal.D2)]
    without = {
        "distortion": best(np.zeros_like(cal.D1), np.zeros_like(cal.D2), zero, cal.R),
        "rotation": best(cal.D1, cal.D2, zero, np.eye(3)),
    }
    if zero:
        without["offset"] = best(cal.D1, cal.D2, False, cal.R)
    remedies: dict[str, list[tuple[str, tuple[float, float]]]] = {
        "offset": [
            (
                options(False, without.get("offset", (0.0, alpha))[1]),
                without.get("offset", (0.0, alpha)),
            )
        ],
        "distortion": [],
        "rotation": [],  # a property of the rig: no option removes it
    }
    k3_share, k3_alpha = best(no_k3[0], no_k3[1], zero, cal.R)
    remedies["distortion"].append((options(zero, k3_alpha, True), (k3_share, k3_alpha)))
    scaled = best(cal.D1, cal.D2, zero, cal.R)
    measured = (
        f"measured, share of the image kept (the smaller of valid and kept pixels, both eyes): "
        f"{solved * 100:.0f} % as solved (--rectify-alpha {alpha:g}, zero disparity "
        f"{'on' if zero else 'off'}); at the best free scaling "
        f"{scaled[0] * 100:.0f} % as solved, "
        + (f"{without['offset'][0] * 100:.0f} % without zero disparity, " if zero else "")
        + f"{without['distortion'][0] * 100:.0f} % without distortion, "
        f"{without['rotation'][0] * 100:.0f} % without the rotation between the eyes; the eyes "
        f"are {angle:.2f}° apart, their principal points {dx:+.1f} px apart in x and {dy:+.1f} "
        f"px in y, k1 {cal.D1[0]:.3f} / {cal.D2[0]:.3f}"
    )
    names = {
        "offset": "the offset between the eyes' principal points (zero disparity gives both "
        "rectified eyes one principal point)",
        "distortion": "the distortion (it bends the image border out of the rectified view)",
        "rotation": "the rotation between the eyes (rectification turns both images by half of it)",
    }
    causes = [k for k in without if without[k][0] - solved >= _SUPPORTED]
    causes.sort(key=lambda k: -without[k][0])
    if not causes:
        text = (
            "no single cause: leaving out the offset, the distortion or the rotation between "
            f"the eyes keeps less than {_SUPPORTED * 100:g} points more"
        )
    else:
        text = "the cause is " + " and ".join(names[k] for k in causes)
    fixes = [
        f"{said} (recomputed: {share * 100:.0f} %)"
        for k in [*causes, *(k for k in remedies if k not in causes)]
        for said, (share, _) in remedies[k]
        if share >= min_fraction and said
    ]
    if scaled[0] >= min_fraction and scaled[0] > solved + 1e-3:
        fixes.append(f"{options(zero, scaled[1])} (recomputed: {scaled[0] * 100:.0f} %)")
    advice = (
        "; remedy: " + "; or ".join(fixes)
        if fixes
        else f"; no rectification option keeps {min_fraction * 100:g} % (--min-rectified-fraction"
        " sets the limit)"
    )
    return f"{text}{advice} ({measured})"


def stereo_gates(
    cal: Calibration, limits: GateLimits, view_names: list[str] | None = None
) -> list[Gate]:
    """Every sanity gate's outcome for ``cal``; ``view_names`` (of the rows of
    ``cal.per_view_rms_px``) let a high RMS name its worst views."""
    gates = _baseline_gates(cal, limits)
    w, h = cal.image_size
    geometry = gates[0].verdict != FAIL  # with swapped eyes the rectification means nothing
    cause: list[str] = []  # measured once, for the first gate that needs it

    def why() -> str:
        if not cause:
            cause.append(rectification_cause(cal, limits.min_rectified_fraction))
        return cause[0]

    points = [(eye, P[0, 2], P[1, 2]) for eye, P in (("left", cal.P1), ("right", cal.P2))]
    outside = [
        (eye, cx, cy)
        for eye, cx, cy in points
        if not (np.isfinite(cx) and np.isfinite(cy) and 0 <= cx < w and 0 <= cy < h)
    ]
    if abs(cal.doffs) > 1e-6:  # each eye keeps its own: the valid-area gate judges the crop
        outside = [(eye, cx, cy) for eye, cx, cy in outside if not np.isfinite(cx + cy)]
    gates.append(
        Gate(
            "rectified principal points",
            " / ".join(f"{eye} ({cx:.1f}, {cy:.1f}) px" for eye, cx, cy in points),
            f"inside the {w}x{h} image"
            + (
                " (not required: zero disparity off, doffs stored)" if abs(cal.doffs) > 1e-6 else ""
            ),
            UNCHECKED if not geometry else FAIL if outside else PASS,
            None
            if not (geometry and outside)
            else "; ".join(
                f"rectified {eye} principal point ({cx:.1f}, {cy:.1f}) px lies outside the "
                f"{w}x{h} image"
                for eye, cx, cy in outside
            )
            + ": "
            + why(),
        )
    )
    fractions = {
        eye: rectified_fractions(K, D, R, P, cal.image_size)
        for eye, K, D, R, P in (
            ("left", cal.K1, cal.D1, cal.R1, cal.P1),
            ("right", cal.K2, cal.D2, cal.R2, cal.P2),
        )
    }
    low = {eye: f for eye, f in fractions.items() if min(f) < limits.min_rectified_fraction}
    alpha = float(cal.info.get("rectify_alpha", 0.0))
    gates.append(
        Gate(
            "rectified image kept",
            " / ".join(f"{eye} {min(f) * 100:.0f} %" for eye, f in fractions.items())
            + (f" (--rectify-alpha {alpha:g})" if alpha >= 0 else ""),
            f">= {limits.min_rectified_fraction * 100:g} % (--min-rectified-fraction)",
            UNCHECKED if not geometry else FAIL if low else PASS,
            None
            if not (geometry and low)
            else "; ".join(
                f"rectified {eye} image shows {valid * 100:.0f} % valid pixels and keeps "
                f"{kept * 100:.0f} % of the camera image"
                for eye, (valid, kept) in low.items()
            )
            + f" (limit {limits.min_rectified_fraction * 100:g} %, --min-rectified-fraction): "
            + why(),
        )
    )
    finite = [v for v in (cal.rms_left_px, cal.rms_right_px, cal.rms_stereo_px) if np.isfinite(v)]
    rms = max(finite, default=float("nan"))
    high = np.isfinite(rms) and rms > limits.max_rms_px
    gates.append(
        Gate(
            "RMS reprojection error",
            f"{rms:.3f} px" if np.isfinite(rms) else "not stored",
            f"<= {limits.max_rms_px:g} px (--max-rms-px)",
            UNCHECKED if not np.isfinite(rms) else FAIL if high else PASS,
            None
            if not high
            else (
                f"RMS reprojection error {rms:.3f} px (left {cal.rms_left_px:.3f}, right "
                f"{cal.rms_right_px:.3f}, stereo {cal.rms_stereo_px:.3f}) is above the "
                f"limit {limits.max_rms_px:g} px (--max-rms-px)" + _rms_remedy(cal, view_names)
            ),
        )
    )
    for gate in gates:
        log.info("gate %s: %s (limit %s): %s", gate.name, gate.measured, gate.limit, gate.verdict)
    return gates


def stereo_problems(
    cal: Calibration, limits: GateLimits, view_names: list[str] | None = None
) -> list[str]:
    """Why ``cal`` is not a usable stereo calibration (empty when it passes every gate), each
    with the quantity, its value and limit, and a remedy (:func:`stereo_gates`)."""
    return [g.problem for g in stereo_gates(cal, limits, view_names) if g.problem]


def _rms_remedy(cal: Calibration, view_names: list[str] | None) -> str:
    """Why the RMS is high, as far as the per-view RMS tells: a few bad views (named) or all."""
    per_view = cal.per_view_rms_px
    if per_view is None or view_names is None or len(view_names) != len(per_view):
        return ": check the board options match the printed board"
    worst = per_view.max(axis=1)
    median = float(np.median(worst))
    bad = [
        f"{view_names[i]} ({worst[i]:.2f} px)"
        for i in np.argsort(worst)[::-1]
        if worst[i] > 2 * median
    ][:5]
    if bad:
        return (
            f": a few views fit much worse than the median view ({median:.2f} px): "
            f"{', '.join(bad)}; retake or remove them"
        )
    return (
        f": every view fits about as badly (median {median:.2f} px): check the board options "
        "(--inner-corners/--squares-x/-y) match the printed board, or for a coarse camera "
        "raise --max-rms-px"
    )


def camera_problems(
    K: np.ndarray, size: tuple[int, int], rms_px: float, limits: GateLimits
) -> list[str]:
    """Why a single-camera calibration is unusable (empty when it passes)."""
    problems = []
    w, h = size
    if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0):
        problems.append(f"focal length ({K[0, 0]:.1f}, {K[1, 1]:.1f}) px is not positive")
    if not (0 <= K[0, 2] < w and 0 <= K[1, 2] < h):
        problems.append(
            f"principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) px lies outside the {w}x{h} image"
        )
    if not np.isfinite(rms_px) or rms_px > limits.max_rms_px:
        problems.append(
            f"RMS reprojection error {rms_px:.3f} px is above the limit "
            f"{limits.max_rms_px:g} px (--max-rms-px): check the board options "
            "match the printed board, or for a coarse camera raise --max-rms-px"
        )
    return problems
