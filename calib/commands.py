"""The ``vbfe calibrate`` commands as Python functions (the CLI only parses and shows progress).

Each takes the rig configuration (:class:`~vbfe.calib.options.CalibConfig`, e.g.
``vbfe.rig_config.load_rig()``) for the board and thresholds of its ``[calib]`` table.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vbfe.acquire.recording.frame_feed import frame_feed
from vbfe.calib.board import BoardSpec, write_board
from vbfe.calib.calibration import Calibration, load_calibration
from vbfe.calib.camera import CameraOptions
from vbfe.calib.camera_model import CameraModel
from vbfe.calib.capture import (
    CaptureOptions,
    CaptureResult,
    Verdict,
    ViewCollector,
    camera_frames,
    capture_views,
)
from vbfe.calib.check import CheckResult, check_calibration
from vbfe.calib.export import export_calibration, export_paths
from vbfe.calib.gates import GateLimits, stereo_problems
from vbfe.calib.importers import import_calibration
from vbfe.calib.mono import MonoResult, calibrate_mono
from vbfe.calib.options import C, CalibConfig, calib_settings
from vbfe.calib.pairs import LIST_SUFFIXES
from vbfe.calib.projector import (
    ProjectorOptions,
    calibrate_projector,
    load_captures,
    with_projector,
)
from vbfe.calib.projector_capture import (
    GrayCaptureOptions,
    capture_gray_code,
    captured_projector_size,
)
from vbfe.calib.report import write_report
from vbfe.calib.stereo import StereoOptions, StereoResult, calibrate_stereo
from vbfe.calib.views import ViewSet, load_images, load_views
from vbfe.common.errors import CalibrationError
from vbfe.drivers.registry import open_rig
from vbfe.drivers.rig import RigOptions

Config = CalibConfig


def _calib(config: Config) -> dict[str, Any]:
    """The ``[calib]`` table, as a fresh dict."""
    return dict(config.tables["calib"])


def board_spec(config: Config, **overrides: Any) -> BoardSpec:
    """The board of the ``[calib]`` table, with overrides (``target``, ``squares_x``,
    ``inner_corners``, ``square_mm``, ...) where they are not ``None``."""
    table = _calib(config)
    if overrides.get("inner_corners") is not None and overrides.get("target") is None:
        overrides = {**overrides, "target": "chessboard"}  # only chessboards count inner corners
    table.update({k: v for k, v in overrides.items() if v is not None})
    return BoardSpec.from_config(table)


def board_scene(config: C) -> C:
    """``config`` with the simulated bench showing the ``[calib]`` board (moved by hand), as
    capturing views needs; a rig whose camera is not simulated is returned unchanged."""
    if config.tables["camera"].get("backend") != "sim":
        return config
    spec = board_spec(config)
    bench = {
        "scene": "board",
        "board": spec.target,
        "board_squares_x": spec.squares_x,
        "board_squares_y": spec.squares_y,
        "board_square_mm": spec.square_m * 1e3,
        "board_marker_mm": spec.marker_m * 1e3,
        "board_dictionary": spec.dictionary,
        "board_legacy": spec.legacy,
    }
    return config.updated({"bench": bench}, "the board scene")


def make_board(config: Config, out_stem: str | Path, **overrides: Any) -> tuple[Path, Path]:
    """Write the printable board (PNG and true-scale PDF)."""
    spec = board_spec(config, **overrides)
    if spec.target != "charuco":
        raise CalibrationError(
            "'calibrate board' writes ChArUco boards; for a chessboard print "
            "any chessboard with a white margin and measure its squares"
        )
    spec.board()  # validates dictionary and sizes before anything is written
    return write_board(spec, out_stem)


def capture(
    config: Config,
    folder: str | Path,
    max_frames: int = 200,
    seed: int | None = None,
    on_view: Callable[[Verdict, ViewCollector, np.ndarray], None] | None = None,
    **overrides: Any,
) -> CaptureResult:
    """Collect calibration views from the rig's camera into ``folder`` (PNG pairs).

    The camera is read through its driver; on the simulated bench choose ``scene = "board"`` in
    ``[bench]`` (``seed`` replaces the bench's seed, i.e. the board's poses).
    """
    spec = board_spec(config, **overrides)
    options = CaptureOptions.from_config(_calib(config))
    with frame_feed(open_rig(config, RigOptions(seed=seed), ("camera",))) as frames:
        return capture_views(camera_frames(frames, max_frames), spec, folder, options, on_view)


def projector_capture(
    config: Config,
    folder: str | Path,
    n_poses: int,
    seed: int | None = None,
    on_event: Callable[[str], None] | None = None,
) -> list[Path]:
    """Show the Gray-code sequence through the rig's projector at ``n_poses`` board poses and
    write the left camera's images into ``folder`` (``pose_NNN/``, after those already there)."""
    options = GrayCaptureOptions.from_config(_calib(config))
    rig = open_rig(config, RigOptions(seed=seed), ("camera", "projector"))
    with frame_feed(rig) as frames:
        return capture_gray_code(frames, rig.projector, folder, n_poses, options, on_event)


@dataclass
class StereoOutcome:
    """What :func:`stereo` wrote, the board and the views it calibrated from."""

    result: StereoResult
    yaml_path: Path
    report_paths: tuple[Path, Path] | None
    spec: BoardSpec
    views: ViewSet


def _calib_table(config: Config, settings: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``[calib]`` table with ``settings`` (keys of the table, e.g. from command-line
    flags) in place of its values."""
    return {**_calib(config), **(settings or {})}


def _gate_table(
    config: Config, settings: dict[str, Any] | None, recorded_with_rig: bool
) -> dict[str, Any]:
    """The ``[calib]`` table for gating views or a file: the configuration's nominal baseline
    is that of the rig the configuration describes (the bench's 4 mm by default), so it is
    checked for sessions recorded with it; for image folders and other tools' files only when
    ``settings`` state one (a command-line flag, or the user's own rig file)."""
    table = _calib_table(config, settings)
    if not recorded_with_rig and "nominal_baseline_mm" not in (settings or {}):
        table["nominal_baseline_mm"] = 0.0
    return table


def is_session(source: str | Path | None) -> bool:
    """Whether a views source is a recorded session (not a folder, image list or glob)."""
    return (
        source is not None
        and Path(source).is_file()
        and Path(source).suffix.lower() not in LIST_SUFFIXES
    )


def stereo(
    config: Config,
    source: str | Path | None,
    out_path: str | Path,
    report: bool = True,
    store_in_session: str | Path | None = None,
    step: Callable[[], None] | None = None,
    left_glob: str | None = None,
    right_glob: str | None = None,
    intrinsics: tuple[str | Path, str | Path] | None = None,
    settings: dict[str, Any] | None = None,
    ext: str | None = None,
    pairs_file: str | Path | None = None,
    swap_eyes: bool = False,
    **overrides: Any,
) -> StereoOutcome:
    """Calibrate from a folder of view pairs (any layout of
    :data:`~vbfe.calib.pairs.PAIR_NAMING`; ``ext`` picks one image type), an image list, a CSV
    of pairs (``pairs_file``), ``--left``/``--right`` globs or a session, with the cameras'
    intrinsics solved or fixed from two camera files (``swap_eyes`` exchanges the eyes); refuse
    a result failing the sanity gates; write the YAML (and report). ``settings`` replace
    ``[calib]`` values; a nominal baseline is checked as :func:`_gate_table` says."""
    spec = board_spec(config, **overrides)
    views = load_views(
        source,
        left_glob=left_glob,
        right_glob=right_glob,
        ext=ext,
        pairs_file=pairs_file,
        swap_eyes=swap_eyes,
    )
    fixed = (
        None
        if intrinsics is None
        else (CameraModel.load(intrinsics[0]), CameraModel.load(intrinsics[1]))
    )
    if fixed is not None and swap_eyes:
        fixed = (fixed[1], fixed[0])
    options = StereoOptions.from_config(
        _gate_table(config, settings, is_session(source) and left_glob is None)
    )
    result = calibrate_stereo(views, spec, options, step, fixed)
    result.calibration.info["unpaired_files"] = views.unpaired
    out_path = Path(out_path)
    result.calibration.save(out_path)
    reports = write_report(result, views, out_path.with_suffix("")) if report else None
    if store_in_session is not None:
        from vbfe.acquire import store_calibration

        store_calibration(store_in_session, result.calibration.to_yaml_text())
    return StereoOutcome(result, out_path, reports, spec, views)


def camera(
    config: Config,
    source: str | Path,
    out_path: str | Path,
    eye: str | None = None,
    step: Callable[[], None] | None = None,
    settings: dict[str, Any] | None = None,
    ext: str | None = None,
    **overrides: Any,
) -> MonoResult:
    """Calibrate one camera from a folder or glob of images (or one eye of stereo views; only
    files ending in ``ext`` when given); write the camera YAML. ``settings`` replace
    ``[calib]`` values."""
    spec = board_spec(config, **overrides)
    table = _calib_table(config, settings)
    result = calibrate_mono(
        load_images(source, eye, ext=ext),
        spec,
        CameraOptions.from_config(table),
        GateLimits.from_config(table),
        step,
        camera=eye or "camera",
    )
    result.model.save(out_path)
    return result


def import_files(
    config: Config,
    paths: list[str | Path],
    out_path: str | Path,
    image_size: tuple[int, int] | None = None,
    unit_mm: float = 1000.0,
    settings: dict[str, Any] | None = None,
) -> tuple[Calibration, str]:
    """Read another tool's calibration (:func:`import_calibration`), refuse it when it fails
    the sanity gates, write it as vbfe's calibration file; returns it and the format read."""
    calibration, fmt = import_calibration(paths, image_size, unit_mm * 1e-3)
    problems = stereo_problems(
        calibration, GateLimits.from_config(_gate_table(config, settings, False))
    )
    if problems:
        raise CalibrationError(
            f"{' + '.join(map(str, paths))}: imported {fmt} calibration "
            "refused, nothing written: " + "; ".join(problems)
        )
    calibration.save(out_path)
    return calibration, fmt


def export_targets(
    calibration_path: str | Path, fmt: str, out_dir: str | Path | None = None
) -> list[Path]:
    """The files :func:`export` writes."""
    path = Path(calibration_path)
    return export_paths(fmt, out_dir or path.parent, path.stem)


def export(calibration_path: str | Path, fmt: str, out_dir: str | Path | None = None) -> list[Path]:
    """Write the calibration in another tool's format next to it (or into ``out_dir``)."""
    path = Path(calibration_path)
    return export_calibration(load_calibration(path), fmt, out_dir or path.parent, path.stem)


def projector(
    config: Config,
    captures_folder: str | Path,
    calibration_path: str | Path,
    out_path: str | Path | None = None,
    simulate_poses: int = 0,
    seed: int | None = None,
    **overrides: Any,
) -> Calibration:
    """Calibrate the projector from Gray-code captures (``pose_NNN/`` folders) and add it to the
    calibration. ``simulate_poses`` > 0 first captures that many poses with the rig's camera and
    projector (see :func:`projector_capture`)."""
    spec = board_spec(config, **overrides)
    calibration = load_calibration(calibration_path)
    if simulate_poses:
        projector_capture(config, captures_folder, simulate_poses, seed)
    projector_size = _projector_size(config, captures_folder)
    result = calibrate_projector(
        load_captures(captures_folder),
        spec,
        calibration,
        projector_size,
        ProjectorOptions.from_config(_calib(config)),
    )
    updated = with_projector(calibration, result, projector_size)
    updated.save(out_path or calibration_path)
    return updated


def _projector_size(config: Config, captures_folder: str | Path) -> tuple[int, int]:
    """``[calib] projector_width/height``, else the size the captures were made for, else the
    configured projector's."""
    table = config.calib
    if table.projector_width and table.projector_height:
        return table.projector_width, table.projector_height
    size = captured_projector_size(captures_folder)
    if size is not None:
        return size
    projector = open_rig(config, families=("projector",)).projector
    if not (projector.width and projector.height):
        raise CalibrationError(
            f"the projector size is unknown ({captures_folder} has no "
            "projector.json); set [calib] projector_width and "
            "projector_height"
        )
    return int(projector.width), int(projector.height)


def _stored_board(stored: Calibration, config: Config, overrides: dict[str, Any]) -> BoardSpec:
    """The board the stored calibration was made with, unless board options are given (or it
    records none)."""
    board = stored.info.get("board")
    if any(v is not None for v in overrides.values()) or not isinstance(board, dict):
        return board_spec(config, **overrides)
    try:
        return BoardSpec(**board)
    except TypeError:
        raise CalibrationError(
            f"the stored calibration's board {board} is not a board "
            "description; give the board options (--target, ...)"
        ) from None


def check(
    config: Config,
    stored_path: str | Path,
    new_path: str | Path | None = None,
    views_path: str | Path | None = None,
    settings: dict[str, Any] | None = None,
    **overrides: Any,
) -> CheckResult:
    """Go/no-go of the stored calibration: its sanity gates, then against a new one and/or
    fresh board views (of the board stored in the calibration unless board ``overrides`` are
    given). ``settings`` replace ``[calib]`` values; the working distance is the stored one
    unless ``settings`` give ``working_distance_mm``."""
    if new_path is None and views_path is None:
        raise CalibrationError(
            "give a new calibration (--against FILE) or fresh views "
            "(--views FOLDER) to check the stored calibration"
        )
    gate_table = _calib_table(config, settings)
    table = calib_settings(gate_table)
    stored, new = load_calibration(stored_path), None
    if new_path is not None:
        new = load_calibration(new_path)
        if new.image_size != stored.image_size:
            raise CalibrationError(
                f"{new_path} is for {new.image_size[0]}x{new.image_size[1]} "
                f"images, {stored_path} for {stored.image_size[0]}x"
                f"{stored.image_size[1]}: compare calibrations of one camera "
                "mode"
            )
    distance_mm = (settings or {}).get("working_distance_mm")
    return check_calibration(
        stored,
        new=new,
        views=load_views(views_path) if views_path is not None else None,
        spec=_stored_board(stored, config, overrides),
        max_depth_error_m=table.check_max_depth_error_mm / 1e3,
        max_epipolar_px=table.check_max_epipolar_px,
        working_distance_m=None if distance_mm is None else distance_mm / 1e3,
        min_corners=table.min_corners,
        limits=GateLimits.from_config(gate_table),
    )
