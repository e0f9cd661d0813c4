"""Single-camera calibration from views of the board (``vbfe calibrate camera``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from vbfe.calib.board import BoardDetector, BoardSpec
from vbfe.calib.board_mistakes import check_board_options
from vbfe.calib.camera import (
    CameraFit,
    CameraOptions,
    calibrate_camera,
    need_views,
    outlier_views,
    solve_flags,
    weak_note,
)
from vbfe.calib.camera_model import CameraModel
from vbfe.calib.corner_choice import CornerChoice, choose_corners
from vbfe.calib.gates import GateLimits, camera_problems
from vbfe.calib.views import ImageSet, image_size
from vbfe.common.errors import CalibrationError


@dataclass
class MonoResult:
    """The camera model, the final fit, the views left out (name → why) and how each view's
    corners were made."""

    model: CameraModel
    fit: CameraFit
    names: list[str]
    dropped: dict[str, str] = field(default_factory=dict)
    weak: str | None = None  # why the result is weakly determined, if it is
    corners: list[CornerChoice] = field(default_factory=list)  # per kept view


def calibrate_mono(
    images: ImageSet,
    spec: BoardSpec,
    options: CameraOptions | None = None,
    limits: GateLimits | None = None,
    step: Callable[[], None] | None = None,
    camera: str = "camera",
) -> MonoResult:
    """Detect the board in every image, drop views with too few corners, keep each view's
    best-fitting corners (:func:`choose_corners`), drop outlier views, calibrate with corner
    rejection; refuse an unusable result (``CalibrationError``). ``camera`` names the camera
    (``left``/``right`` for one eye of stereo views) in the rejected corners and the reasons
    views were dropped."""
    options, limits = options or CameraOptions(), limits or GateLimits()
    size = image_size(images)
    check_board_options(images.images, spec, images.source, options.min_corners)
    detector = BoardDetector(spec, candidates=True)
    names, dets, dropped = [], [], {}
    for name, image in zip(images.names, images.images, strict=False):
        det = detector.detect(image)
        if step:
            step()
        if len(det) < options.min_corners:
            dropped[name] = f"too few corners ({len(det)}; need {options.min_corners})"
            continue
        names.append(name)
        dets.append(det)
    if not dets:
        raise CalibrationError(
            f"no {spec.name} found in any of the {len(images)} images of "
            f"{images.source}; check the board options ({spec.describe()}) "
            f"match the printed board{spec.size_hint()}"
        )
    need_views(len(dets), options, images.source, dropped)
    dets, corners = choose_corners(spec, dets, names, size, camera, solve_flags(options))
    outliers, fit = outlier_views(spec, dets, names, size, camera, options)
    if outliers:
        keep = [n not in outliers for n in names]
        dets = [d for d, k in zip(dets, keep, strict=False) if k]
        names = [n for n, k in zip(names, keep, strict=False) if k]
        dropped.update(outliers)
        need_views(len(dets), options, images.source, dropped)
        fit = calibrate_camera(
            spec,
            dets,
            names,
            size,
            camera,
            options.outlier_sigma,
            options.outlier_min_px,
            flags=solve_flags(options),
        )
    problems = camera_problems(fit.K, size, fit.rms_px, limits)
    if problems:
        raise CalibrationError(
            f"{images.source}: calibration refused, nothing written: " + "; ".join(problems)
        )
    model = CameraModel(
        K=fit.K,
        D=fit.D,
        image_size=size,
        rms_px=fit.rms_px,
        per_view_rms_px=fit.per_view_rms_px,
        std_intrinsics=fit.std_intrinsics,
        views=names,
        dropped=[f"{n}: {why}" for n, why in dropped.items()],
        board=spec.describe(),
    )
    kept = [c for c in corners if c.view in names]
    return MonoResult(model, fit, names, dropped, weak_note(len(names), options), kept)
