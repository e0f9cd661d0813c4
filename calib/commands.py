"""The ``vbfe calibrate`` commands as Python functions (the CLI only parses and shows progress).

Each takes the rig configuration (``vbfe.config.load_config``) for the board and thresholds of
its ``[calib]`` table.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vbfe.calib.board import BoardSpec, write_board
from vbfe.calib.calibration import Calibration, load_calibration
from vbfe.calib.capture import (CaptureOptions, CaptureResult, Verdict, ViewCollector,
                                camera_frames, capture_views)
from vbfe.calib.check import CheckResult, check_calibration
from vbfe.calib.errors import CalibrationError
from vbfe.calib.options import calib_settings
from vbfe.calib.projector import (ProjectorOptions, calibrate_projector, load_captures,
                                  save_captures, with_projector)
from vbfe.calib.report import write_report
from vbfe.calib.sim_source import bench_rig, simulated_board_frames, simulated_gray_code_captures
from vbfe.calib.stereo import StereoOptions, StereoResult, calibrate_stereo
from vbfe.calib.views import load_views
from vbfe.config import section

Config = dict[str, dict[str, Any]]


def board_spec(config: Config, **overrides: Any) -> BoardSpec:
    """The board of the ``[calib]`` table, with overrides (``squares_x``, ``square_mm``, ...)
    where they are not ``None``."""
    table = section(config, "calib")
    table.update({k: v for k, v in overrides.items() if v is not None})
    return BoardSpec.from_config(table)


def make_board(config: Config, out_stem: str | Path, **overrides: Any) -> tuple[Path, Path]:
    """Write the printable board (PNG and true-scale PDF)."""
    spec = board_spec(config, **overrides)
    spec.board()  # validates dictionary and sizes before anything is written
    return write_board(spec, out_stem)


def capture(config: Config, folder: str | Path, max_frames: int = 200, seed: int | None = None,
            on_view: Callable[[Verdict, ViewCollector, np.ndarray], None] | None = None,
            **overrides: Any) -> CaptureResult:
    """Collect calibration views from the rig's camera into ``folder`` (PNG pairs).

    With the simulated camera the board is rendered at random hand-held poses on the bench's
    rig (some held still, some blurred); a real camera is read through its driver.
    """
    spec = board_spec(config, **overrides)
    options = CaptureOptions.from_config(section(config, "calib"))
    camera_table = section(config, "camera")
    if camera_table.get("backend", "sim") == "sim":
        bench = section(config, "bench")
        rng = np.random.default_rng(bench.get("seed", 0) if seed is None else seed)
        frames = simulated_board_frames(bench_rig(bench), spec, max_frames, rng)
        return capture_views(frames, spec, folder, options, on_view)
    from vbfe.drivers.registry import open_device

    with open_device("camera", camera_table) as camera:
        return capture_views(camera_frames(camera, max_frames), spec, folder, options, on_view)


@dataclass
class StereoOutcome:
    """What :func:`stereo` wrote."""

    result: StereoResult
    yaml_path: Path
    report_paths: tuple[Path, Path] | None


def stereo(config: Config, source: str | Path, out_path: str | Path,
           report: bool = True, store_in_session: str | Path | None = None,
           step: Callable[[], None] | None = None, **overrides: Any) -> StereoOutcome:
    """Calibrate from a folder of view pairs or a session; write the YAML (and report)."""
    spec = board_spec(config, **overrides)
    views = load_views(source)
    result = calibrate_stereo(views, spec, StereoOptions.from_config(section(config, "calib")),
                              step)
    out_path = Path(out_path)
    result.calibration.save(out_path)
    reports = write_report(result, views, out_path.with_suffix("")) if report else None
    if store_in_session is not None:
        from vbfe.acquire import store_calibration

        store_calibration(store_in_session, result.calibration.to_yaml_text())
    return StereoOutcome(result, out_path, reports)


def projector(config: Config, captures_folder: str | Path, calibration_path: str | Path,
              out_path: str | Path | None = None, simulate_poses: int = 0,
              seed: int | None = None, **overrides: Any) -> Calibration:
    """Calibrate the projector from Gray-code captures (``pose_NNN/`` folders) and add it to the
    calibration. ``simulate_poses`` > 0 first renders that many poses on the simulated bench."""
    spec = board_spec(config, **overrides)
    calibration = load_calibration(calibration_path)
    bench = section(config, "bench")
    rig = bench_rig(bench)
    projector_size = _projector_size(config, rig)
    if simulate_poses:
        rng = np.random.default_rng(bench.get("seed", 0) if seed is None else seed)
        save_captures(captures_folder, simulated_gray_code_captures(rig, spec, simulate_poses,
                                                                    rng))
    result = calibrate_projector(load_captures(captures_folder), spec, calibration,
                                 projector_size, ProjectorOptions.from_config(section(config,
                                                                                      "calib")))
    updated = with_projector(calibration, result, projector_size)
    updated.save(out_path or calibration_path)
    return updated


def _projector_size(config: Config, rig) -> tuple[int, int]:
    table = calib_settings(section(config, "calib"))
    if table.projector_width and table.projector_height:
        return table.projector_width, table.projector_height
    return rig.projector.width, rig.projector.height


def check(config: Config, stored_path: str | Path, new_path: str | Path | None = None,
          views_path: str | Path | None = None, max_depth_error_mm: float | None = None,
          **overrides: Any) -> CheckResult:
    """Go/no-go of the stored calibration against a new one and/or fresh board views."""
    if new_path is None and views_path is None:
        raise CalibrationError("give a new calibration (--against FILE) or fresh views "
                               "(--views FOLDER) to check the stored calibration")
    table = calib_settings(section(config, "calib"))
    stored, new = load_calibration(stored_path), None
    if new_path is not None:
        new = load_calibration(new_path)
        if new.image_size != stored.image_size:
            raise CalibrationError(f"{new_path} is for {new.image_size[0]}x{new.image_size[1]} "
                                   f"images, {stored_path} for {stored.image_size[0]}x"
                                   f"{stored.image_size[1]}: compare calibrations of one camera "
                                   "mode")
    limit_mm = max_depth_error_mm if max_depth_error_mm is not None else \
        table.check_max_depth_error_mm
    return check_calibration(
        stored, new=new,
        views=load_views(views_path) if views_path is not None else None,
        spec=board_spec(config, **overrides), max_depth_error_m=limit_mm / 1e3,
        max_epipolar_px=table.check_max_epipolar_px, min_corners=table.min_corners)
