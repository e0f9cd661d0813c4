"""Stereo calibration: detection, per-camera calibration with outlier views and corners
rejected, stereo calibration with desynchronisation detection, rectification, sanity gates and
uncertainty."""

from __future__ import annotations

import dataclasses
import datetime
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from vbfe.calib.board import BoardDetector, BoardSpec, Detection
from vbfe.calib.board_mistakes import check_board_options
from vbfe.calib.calibration import Calibration
from vbfe.calib.camera import (
    CRITERIA,
    CameraFit,
    CameraOptions,
    calibrate_camera,
    need_views,
    outlier_views,
    points,
    residuals,
    solve_flags,
    weak_note,
)
from vbfe.calib.camera_model import CameraModel
from vbfe.calib.chessboard import is_clear, same_numbering
from vbfe.calib.corner_choice import CornerChoice, choose_corners, counts
from vbfe.calib.gates import FAIL, GateLimits, stereo_gates
from vbfe.calib.options import calib_field, from_table
from vbfe.calib.rectify import Rectification, rectified_fractions, rectify, usable
from vbfe.calib.uncertainty import StereoSolve, UncertaintyMap, uncertainty_map
from vbfe.calib.views import ViewSet, check_sizes
from vbfe.common.errors import CalibrationError


@dataclass
class StereoOptions(CameraOptions):
    """Knobs of :func:`calibrate_stereo` (defaults: the ``[calib]`` table)."""

    desync_min_px: float = calib_field("desync_min_px")
    reject_desync: bool = calib_field("reject_desync")
    rectify_alpha: float = calib_field("rectify_alpha")
    zero_disparity: str = calib_field("zero_disparity")  # auto | on | off
    working_distance_m: float = calib_field("working_distance_mm", 1e-3)
    gates: GateLimits = field(default_factory=GateLimits)

    @classmethod
    def from_config(cls, calib_table: dict) -> StereoOptions:
        """Options from a rig config's ``[calib]`` table."""
        options = from_table(cls, calib_table)
        options.gates = GateLimits.from_config(calib_table)
        return options


@dataclass
class StereoResult:
    """A calibration plus everything the report shows."""

    calibration: Calibration
    names: list[str]  # views used in the final stereo solve
    left: CameraFit
    right: CameraFit
    stereo_detections: list[tuple[Detection, Detection]]
    dropped: dict[str, str] = field(default_factory=dict)  # view -> why
    desync: dict[str, tuple[float, float]] = field(default_factory=dict)  # view -> (dx, dy) px
    weak: str | None = None  # why the result is weakly determined, if it is
    renumbered: list[str] = field(default_factory=list)  # chessboard views whose eyes disagreed
    uncertainty: UncertaintyMap | None = None  # depth σ over the image, board coverage
    corners: list[CornerChoice] = field(default_factory=list)  # per kept view and eye


def detect_views(
    views: ViewSet, spec: BoardSpec, step: Callable[[], None] | None = None
) -> list[tuple[Detection, Detection]]:
    """Board corners in the left and right image of every view, with their refinement
    candidates."""
    detector = BoardDetector(spec, candidates=True)
    out = []
    for left, right in views.pairs:
        out.append((detector.detect(left), detector.detect(right)))
        if step:
            step()
    return out


def _select(det: Detection, ids: np.ndarray) -> Detection:
    keep = np.isin(det.ids, ids)
    return Detection(det.ids[keep], det.corners[keep])


def _stereo_solve(
    spec: BoardSpec,
    pairs: list[tuple[Detection, Detection]],
    left: CameraFit,
    right: CameraFit,
    image_size: tuple[int, int],
    fixed: bool,
    flags: int,
):
    obj, img_l = points(spec.object_points(), [p[0] for p in pairs])
    _, img_r = points(spec.object_points(), [p[1] for p in pairs])
    flags |= cv2.CALIB_FIX_INTRINSIC if fixed else cv2.CALIB_USE_INTRINSIC_GUESS
    try:
        # OpenCV takes None for R, T (no initial guess); its stubs do not say so
        (rms, K1, D1, K2, D2, R, T, _, _, rvecs, tvecs, per_view) = cv2.stereoCalibrateExtended(  # type: ignore[call-overload]
            obj,
            img_l,
            img_r,
            left.K.copy(),
            left.D.copy(),
            right.K.copy(),
            right.D.copy(),
            image_size,
            None,
            None,
            flags=flags,
            criteria=CRITERIA,
        )
    except cv2.error as exc:
        raise CalibrationError(
            f"stereo calibration failed in OpenCV ({str(exc).strip().splitlines()[-1]})"
        ) from None
    return rms, K1, D1.reshape(-1), K2, D2.reshape(-1), R, T.reshape(3), rvecs, tvecs, per_view


def _relative_poses(left: CameraFit, right: CameraFit) -> tuple[np.ndarray, np.ndarray]:
    """Left→right rotation vectors and translations (m) implied by each view's independent
    left and right board poses (n×3 each)."""
    rvecs, tvecs = [], []
    for rl, tl, rr, tr in zip(left.rvecs, left.tvecs, right.rvecs, right.tvecs, strict=False):
        Rl, _ = cv2.Rodrigues(rl)
        Rr, _ = cv2.Rodrigues(rr)
        Rrel = Rr @ Rl.T
        rvecs.append(cv2.Rodrigues(Rrel)[0].reshape(3))
        tvecs.append(tr.reshape(3) - Rrel @ tl.reshape(3))
    return np.asarray(rvecs), np.asarray(tvecs)


def desync_shifts(spec: BoardSpec, left: CameraFit, right: CameraFit) -> np.ndarray:
    """Per view, how far (px, n×2) the right image's corners sit from where the left image's
    board pose and the consensus (median) left→right transform put them.

    Left and right taken at the same instant leave zero-mean noise; a board that moved between
    the two exposures leaves a shift common to all corners of the view.
    """
    rel_r, rel_t = _relative_poses(left, right)
    R, _ = cv2.Rodrigues(np.median(rel_r, axis=0))
    T = np.median(rel_t, axis=0)
    obj_all = spec.object_points()
    out = np.zeros((len(left.rvecs), 2))
    views = zip(right.detections, left.rvecs, left.tvecs, strict=False)
    for v, (dr, rvec, tvec) in enumerate(views):
        Rl, _ = cv2.Rodrigues(rvec)
        rr, _ = cv2.Rodrigues(R @ Rl)
        out[v] = -residuals(
            obj_all[dr.ids], dr.corners, rr, R @ tvec.reshape(3) + T, right.K, right.D
        ).mean(axis=0)
    return out


def _flag_desync(shifts: np.ndarray, min_px: float) -> np.ndarray:
    mag = np.linalg.norm(shifts, axis=1)
    spread = 1.4826 * np.median(np.abs(mag - np.median(mag)))
    return mag > max(min_px, np.median(mag) + 6 * spread)


def epipolar_errors(calibration: Calibration, left: Detection, right: Detection) -> np.ndarray:
    """Row differences (px) of common corners after rectification (0 for a perfect calibration)."""
    common = np.intersect1d(left.ids, right.ids)
    if len(common) == 0:
        return np.zeros(0)
    pl, pr = calibration.rectify_points(
        _select(left, common).corners, _select(right, common).corners
    )
    return pr[:, 1] - pl[:, 1]


def _keep_views(fit: CameraFit, keep: np.ndarray) -> CameraFit:
    return dataclasses.replace(
        fit,
        per_view_rms_px=fit.per_view_rms_px[keep],
        rvecs=[r for r, k in zip(fit.rvecs, keep, strict=False) if k],
        tvecs=[t for t, k in zip(fit.tvecs, keep, strict=False) if k],
        detections=[d for d, k in zip(fit.detections, keep, strict=False) if k],
    )


def calibrate_stereo(
    views: ViewSet,
    spec: BoardSpec,
    options: StereoOptions | None = None,
    step: Callable[[], None] | None = None,
    intrinsics: tuple[CameraModel, CameraModel] | None = None,
) -> StereoResult:
    """Calibrate the stereo pair from board views: detect corners, drop views with too few,
    drop outlier views, calibrate each camera with corner rejection (or take fixed
    ``intrinsics``), leave out desynchronised views, then ``stereoCalibrateExtended`` and
    ``stereoRectify``; refuse a result that fails the sanity gates. ``step`` is called per
    detected view."""
    options = options or StereoOptions()
    image_size = check_sizes(views)
    check_board_options([left for left, _ in views.pairs], spec, views.source, options.min_corners)
    detections = detect_views(views, spec, step)
    if all(len(dl) == 0 and len(dr) == 0 for dl, dr in detections):
        raise CalibrationError(
            f"no {spec.name} found in any of the {len(views)} views of {views.source}; check the "
            f"board options ({spec.describe()}) match the printed board{spec.size_hint()}"
        )
    return calibrate_detections(
        detections, views.names, image_size, spec, options, views.source, intrinsics
    )


def _check_intrinsics(
    intrinsics: tuple[CameraModel, CameraModel], image_size: tuple[int, int]
) -> None:
    for eye, model in zip(("left", "right"), intrinsics, strict=False):
        if model.image_size != image_size:
            raise CalibrationError(
                f"--intrinsics: the {eye} camera file is for "
                f"{model.image_size[0]}x{model.image_size[1]} images but the "
                f"views are {image_size[0]}x{image_size[1]}"
            )


def _pose_rms(spec: BoardSpec, detections: list[Detection], model: CameraModel) -> float:
    """RMS (px) of the board poses solved for ``detections`` with ``model``'s intrinsics."""
    obj, img = points(spec.object_points(), detections)
    squares = []
    for o, i in zip(obj, img, strict=True):
        ok, rvec, tvec = cv2.solvePnP(o, i, model.K, model.D)
        if ok:
            squares.append(np.sum(residuals(o, i, rvec, tvec, model.K, model.D) ** 2, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(squares)))) if squares else float("inf")


_EXCHANGED_RATIO = 2.0  # given order fits this many times worse than exchanged: refused


def _check_eye_order(
    spec: BoardSpec,
    pairs: list[tuple[Detection, Detection]],
    intrinsics: tuple[CameraModel, CameraModel],
) -> None:
    """Refuse camera files given in the wrong eye order: a camera file fixed on the other eye
    still fits each view (the board pose absorbs the principal-point offset) but turns the
    eyes apart in the stereo solve, so the rectified principal point leaves the image."""
    lefts, rights = [p[0] for p in pairs], [p[1] for p in pairs]
    given = (_pose_rms(spec, lefts, intrinsics[0]), _pose_rms(spec, rights, intrinsics[1]))
    exchanged = (_pose_rms(spec, lefts, intrinsics[1]), _pose_rms(spec, rights, intrinsics[0]))
    if sum(exchanged) * _EXCHANGED_RATIO < sum(given):
        raise CalibrationError(
            "--intrinsics LEFT RIGHT look exchanged: the board poses fit the left and right "
            f"views with RMS {given[0]:.3f} / {given[1]:.3f} px in the order given, "
            f"{exchanged[0]:.3f} / {exchanged[1]:.3f} px exchanged; give the left eye's "
            "camera file first (and with --swap-eyes, the files as their names say)"
        )


def calibrate_detections(
    detections: list[tuple[Detection, Detection]],
    view_names: list[str],
    image_size: tuple[int, int],
    spec: BoardSpec,
    options: StereoOptions | None = None,
    source: str = "views",
    intrinsics: tuple[CameraModel, CameraModel] | None = None,
) -> StereoResult:
    """Calibrate from corners already detected (one ``(left, right)`` pair per view; each
    eye's best-fitting candidate kept where detections hold several, see
    :func:`choose_corners`); with ``intrinsics`` (left, right) the cameras' intrinsics are
    fixed (``CALIB_FIX_INTRINSIC``)."""
    options = options or StereoOptions()
    given = detections
    fixed = (None, None) if intrinsics is None else intrinsics
    if intrinsics is not None:
        _check_intrinsics(intrinsics, image_size)
    detections, choices = _chosen_corners(detections, view_names, image_size, spec, options, fixed)
    names, pairs, dropped, renumbered = [], [], {}, []
    for name, (dl, dr) in zip(view_names, detections, strict=False):
        if spec.target == "chessboard" and len(dl) and len(dr):
            corners, turned, contrast = same_numbering(dl.corners, dr.corners, spec.inner_corners)
            if not is_clear(contrast):
                dropped[name] = (
                    "the left and right eyes' chessboard corners cannot be matched "
                    f"(both numberings fit, contrast {contrast:.1f}); retake the view "
                    "with the board less turned"
                )
                continue
            if turned:
                renumbered.append(name)
                dr = Detection(dr.ids, corners)
        common = np.intersect1d(dl.ids, dr.ids)
        if len(common) < options.min_corners:
            dropped[name] = (
                f"too few corners (left {len(dl)}, right {len(dr)}, in both "
                f"{len(common)}; need {options.min_corners})"
            )
            continue
        names.append(name)
        pairs.append((dl, dr))
    need_views(len(pairs), options, source, dropped)
    if intrinsics is not None:
        _check_eye_order(spec, pairs, intrinsics)
    outliers, fits = {}, []
    for k, eye in enumerate(("left", "right")):
        found, fit = outlier_views(
            spec, [p[k] for p in pairs], names, image_size, eye, options, fixed[k]
        )
        outliers.update({n: why for n, why in found.items() if n not in outliers})
        fits.append(fit)
    left, right = fits
    if outliers:
        inlier = [n not in outliers for n in names]
        pairs = [p for p, k in zip(pairs, inlier, strict=False) if k]
        names = [n for n, k in zip(names, inlier, strict=False) if k]
        dropped.update(outliers)
        need_views(len(pairs), options, source, dropped)
        left, right = (
            calibrate_camera(
                spec,
                [p[k] for p in pairs],
                names,
                image_size,
                eye,
                options.outlier_sigma,
                options.outlier_min_px,
                fixed=fixed[k],
                flags=solve_flags(options),
            )
            for k, eye in enumerate(("left", "right"))
        )
    stereo_pairs = []
    for dl, dr in zip(left.detections, right.detections, strict=False):
        common = np.intersect1d(dl.ids, dr.ids)
        stereo_pairs.append((_select(dl, common), _select(dr, common)))
    shifts = desync_shifts(spec, left, right)
    flagged = _flag_desync(shifts, options.desync_min_px)
    desync = {names[i]: (float(shifts[i, 0]), float(shifts[i, 1])) for i in np.flatnonzero(flagged)}
    keep = np.ones(len(names), bool)
    if options.reject_desync and flagged.any():
        keep = ~flagged
        if keep.sum() < options.min_views:
            raise CalibrationError(
                f"{source}: {int(flagged.sum())} views look "
                f"desynchronised ({', '.join(desync)}); only {int(keep.sum())} "
                f"left, need {options.min_views} (--min-views); check the "
                "camera's frame sync"
            )
        for n in desync:
            dropped[n] = "left/right captured at different instants (desynchronised)"
        left, right = _keep_views(left, keep), _keep_views(right, keep)
        stereo_pairs = [p for p, k in zip(stereo_pairs, keep, strict=False) if k]
        names = [n for n, k in zip(names, keep, strict=False) if k]
    rms, K1, D1, K2, D2, R, T, rvecs, tvecs, per_view = _stereo_solve(
        spec, stereo_pairs, left, right, image_size, intrinsics is not None, solve_flags(options)
    )
    rect = rectify(
        K1,
        D1,
        K2,
        D2,
        image_size,
        R,
        T,
        options.rectify_alpha,
        options.zero_disparity,
        options.gates.min_rectified_fraction,
    )
    if not usable(rect):
        raise CalibrationError(
            _unrectifiable(rect, rms, options, source)
            + _joint_beside(given, view_names, image_size, spec, options, intrinsics)
        )
    per_view_rms = np.column_stack(
        [
            left.per_view_rms_px,
            right.per_view_rms_px,
            np.sqrt((per_view[:, 0] ** 2 + per_view[:, 1] ** 2) / 2),
        ]
    )
    calibration = Calibration(
        K1=K1,
        D1=D1,
        K2=K2,
        D2=D2,
        R=R,
        T=T,
        R1=rect.R1,
        R2=rect.R2,
        P1=rect.P1,
        P2=rect.P2,
        Q=rect.Q,
        image_size=image_size,
        rms_left_px=left.rms_px,
        rms_right_px=right.rms_px,
        rms_stereo_px=float(rms),
        per_view_rms_px=per_view_rms,
        info={"rectify_alpha": rect.alpha},
    )
    gates = stereo_gates(calibration, options.gates, names)
    problems = [g.problem for g in gates if g.verdict == FAIL and g.problem]
    if problems:
        raise CalibrationError(
            f"{source}: stereo calibration refused, nothing written: "
            + "; ".join(problems)
            + _joint_beside(given, view_names, image_size, spec, options, intrinsics, calibration)
        )
    weak = weak_note(len(names), options)
    calibration.info = _info(
        calibration, spec, options, names, left, right, stereo_pairs, dropped, desync
    )
    calibration.info["renumbered_views"] = renumbered
    calibration.info["zero_disparity"] = rect.zero_disparity
    calibration.info["gates"] = [g.row() for g in gates]
    kept = [c for c in choices if c.view in names]
    calibration.info["corners"] = [c.row() for c in kept]
    calibration.info["views_per_detector"] = counts(kept)
    if weak:
        calibration.info["weakly_determined"] = weak
    solve = StereoSolve(
        K1,
        D1,
        K2,
        D2,
        R,
        T,
        list(rvecs),
        list(tvecs),
        [spec.object_points()[dl.ids] for dl, _ in stereo_pairs],
        [dl.corners for dl, _ in stereo_pairs],
        [dr.corners for _, dr in stereo_pairs],
    )
    uncertainty = uncertainty_map(
        calibration, solve, left, options.working_distance_m, options.fix_k3
    )
    calibration.info["uncertainty"] = {
        "summary": uncertainty.summary(),
        "depth_sigma_m": uncertainty.depth_sigma_m.round(9).tolist(),  # rows of the grid
        "board_views_per_region": uncertainty.coverage.tolist(),
    }  # 3x3, top row first
    return StereoResult(
        calibration,
        names,
        left,
        right,
        stereo_pairs,
        dropped,
        desync,
        weak,
        renumbered,
        uncertainty,
        kept,
    )


def _summary(cal: Calibration) -> str:
    kept = min(
        min(rectified_fractions(K, D, R, P, cal.image_size))
        for K, D, R, P in ((cal.K1, cal.D1, cal.R1, cal.P1), (cal.K2, cal.D2, cal.R2, cal.P2))
    )
    return (
        f"f {cal.f:.2f} px, B {cal.B * 1e3:.4f} mm, {kept * 100:.0f} % of the image kept, "
        f"stereo RMS {cal.rms_stereo_px:.3f} px"
    )


def _joint_beside(
    detections: list[tuple[Detection, Detection]],
    names: list[str],
    image_size: tuple[int, int],
    spec: BoardSpec,
    options: StereoOptions,
    intrinsics: tuple[CameraModel, CameraModel] | None,
    refused: Calibration | None = None,
) -> str:
    """For a refused fixed-intrinsics solve: the joint solve's numbers beside it (empty for a
    joint solve)."""
    if intrinsics is None:
        return ""
    fixed = f" (with --intrinsics: {_summary(refused)})" if refused is not None else ""
    try:
        joint = calibrate_detections(detections, names, image_size, spec, options).calibration
    except CalibrationError as exc:
        why = str(exc).split("nothing written: ", 1)[-1]
        return f"; the joint solve (without --intrinsics) of the same views is refused too: {why}"
    return (
        f"; the joint solve (without --intrinsics) of the same views passes: {_summary(joint)}"
        f"{fixed}: calibrate without --intrinsics, or recalibrate each eye"
    )


def _unrectifiable(rect: Rectification, rms: float, options: StereoOptions, source: str) -> str:
    """Why no rectification came out with positive focal lengths: the pairs only when their own
    stereo reprojection error is above the gate's limit."""
    focal = f"P1[0,0] = {rect.P1[0, 0]:.4g} px, P2[0,0] = {rect.P2[0, 0]:.4g} px"
    if rms > options.gates.max_rms_px:
        return (
            f"{source}: stereo calibration refused, nothing written: the rectified focal lengths "
            f"({focal}) are not positive and the pairs fit with stereo RMS {rms:.3f} px (limit "
            f"{options.gates.max_rms_px:g} px): the views' left and right images do not show the "
            "same board poses; check each pair is one moment of one rig and the board options "
            "match the board"
        )
    return (
        f"{source}: stereo calibration refused, nothing written: OpenCV's stereoRectify gave "
        f"no positive rectified focal length ({focal}) at any free scaling (--rectify-alpha 0 "
        f"to 1) although the pairs fit (stereo RMS {rms:.3f} px): the eyes' rotation and "
        "intrinsics leave no common rectified view"
    )


def _chosen_corners(
    detections: list[tuple[Detection, Detection]],
    names: list[str],
    image_size: tuple[int, int],
    spec: BoardSpec,
    options: StereoOptions,
    fixed: tuple[CameraModel | None, CameraModel | None],
) -> tuple[list[tuple[Detection, Detection]], list[CornerChoice]]:
    """Each eye's best-fitting corners (:func:`choose_corners` over the views where that eye
    sees enough corners) and the record of what was kept."""
    eyes = [[pair[k] for pair in detections] for k in (0, 1)]
    choices: list[CornerChoice] = []
    for k, eye in enumerate(("left", "right")):
        usable = [v for v, d in enumerate(eyes[k]) if len(d) >= options.min_corners]
        chosen, records = choose_corners(
            spec,
            [eyes[k][v] for v in usable],
            [names[v] for v in usable],
            image_size,
            eye,
            solve_flags(options),
            fixed[k],
        )
        for v, det in zip(usable, chosen, strict=True):
            eyes[k][v] = det
        choices += records
    return list(zip(eyes[0], eyes[1], strict=True)), choices


def _info(
    cal: Calibration,
    spec: BoardSpec,
    options: StereoOptions,
    names: list[str],
    left: CameraFit,
    right: CameraFit,
    pairs: list[tuple[Detection, Detection]],
    dropped: dict[str, str],
    desync: dict[str, tuple[float, float]],
) -> dict:
    """Uncertainties and provenance stored with the calibration."""
    baselines = np.linalg.norm(_relative_poses(left, right)[1], axis=1)
    sigma_B = float(np.std(baselines, ddof=1) / np.sqrt(len(baselines)))
    sigma_f = float(np.hypot(left.std_intrinsics[0], left.std_intrinsics[1]) / 2)
    f_K = float((cal.K1[0, 0] + cal.K1[1, 1]) / 2)
    z = options.working_distance_m
    depth_sigma = z * float(np.hypot(sigma_f / f_K, sigma_B / cal.B))
    epi = np.concatenate([epipolar_errors(cal, dl, dr) for dl, dr in pairs])
    names_std = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]
    return {
        "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "opencv_version": cv2.__version__,
        "board": spec.to_dict(),
        "views": names,
        "dropped_views": dropped,
        "rejected_corners": [
            [r.view, r.camera, r.corner_id, round(r.residual_px, 3)]
            for r in left.rejected + right.rejected
        ],
        "desynchronised_views": {k: [round(v[0], 3), round(v[1], 3)] for k, v in desync.items()},
        "std_left": dict(zip(names_std, map(float, left.std_intrinsics), strict=False)),
        "std_right": dict(zip(names_std, map(float, right.std_intrinsics), strict=False)),
        "sigma_B_m": sigma_B,
        "working_distance_m": z,
        "rectify_alpha": cal.info["rectify_alpha"],
        "depth_sigma_at_working_distance_m": depth_sigma,
        "depth_per_px_disparity_at_working_distance_m": z * z / (cal.f * cal.B),
        "epipolar_rms_px": float(np.sqrt(np.mean(epi**2))) if epi.size else float("nan"),
    }
