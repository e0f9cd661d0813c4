"""Honest quality signals of a reconstruction: the disparity range the geometry needs, matches
piled up at its edges, and whether the De Bruijn pattern is visible at all.

Settings come from the rig config's ``[recon]`` table (:class:`ReconSettings`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.common.errors import ReconError
from vbfe.common.settings import parse_table, setting
from vbfe.recon.clouds import CloudReader
from vbfe.recon.matching import SgbmParams

DISPARITY_STEP = 16  # StereoSGBM needs numDisparities to be a multiple of 16
COST_BYTES = 2  # StereoSGBM's CostType (short)
# rows of cost buffers the single-pass modes hold at once (aggregation, window, both passes):
# a bound, not OpenCV's exact figure; MODE_HH holds two for every row of the image
SINGLE_PASS_ROWS = 64
RANGE_FLAGS = (
    "--min-disparity/--num-disparities (or [sgbm] min_disparity/num_disparities, or "
    "the depth range [recon] min_depth_mm/max_depth_mm)"
)


@dataclass(frozen=True)
class ReconSettings:
    """The ``[recon]`` table: the rig's working-distance range and the warning thresholds."""

    min_depth_mm: float = setting(25.0, gt=0)  # nearest surface the disparity range must cover
    max_depth_mm: float = setting(120.0, gt=0)  # farthest
    min_decoded_fraction: float = setting(0.05, ge=0, le=1)  # below this readable share, warn
    max_edge_fraction: float = setting(0.01, ge=0, le=1)  # above this share at the edge, warn

    @classmethod
    def from_config(cls, table: dict[str, Any]) -> ReconSettings:
        """Settings from the ``[recon]`` table of a rig config (unknown keys are an error)."""
        settings = parse_table(cls, table, "recon")
        if not settings.min_depth_mm < settings.max_depth_mm:
            raise ReconError(
                f"[recon] needs 0 < min_depth_mm < max_depth_mm, got "
                f"{settings.min_depth_mm} and {settings.max_depth_mm}"
            )
        return settings


def disparity_range(
    calibration: Calibration, min_depth_mm: float, max_depth_mm: float
) -> tuple[int, int]:
    """``(min_disparity, num_disparities)`` covering depths ``min_depth_mm..max_depth_mm``:
    ``d = f·B/z + disparity_offset``, the count rounded up to a multiple of 16."""
    if not 0 < min_depth_mm < max_depth_mm:
        raise ReconError(f"depth range needs 0 < min < max, got {min_depth_mm}..{max_depth_mm} mm")
    f_b = calibration.f * calibration.B
    if f_b <= 0:
        raise ReconError(
            f"calibration has f·B = {f_b:.3g} px·m; the rectified pair needs a "
            f"positive focal length and baseline (left camera on the left)"
        )
    low = math.floor(f_b / (max_depth_mm * 1e-3) + calibration.disparity_offset)
    high = math.ceil(f_b / (min_depth_mm * 1e-3) + calibration.disparity_offset)
    count = DISPARITY_STEP * max(1, math.ceil((high - low + 1) / DISPARITY_STEP))
    return low, count


def params_for(calibration: Calibration, params: SgbmParams, settings: ReconSettings) -> SgbmParams:
    """``params`` with the range derived from the geometry when ``num_disparities`` is 0."""
    if params.num_disparities:
        return params
    low, count = disparity_range(calibration, settings.min_depth_mm, settings.max_depth_mm)
    return replace(params, min_disparity=low, num_disparities=count)


def narrowed(
    calibration: Calibration, params: SgbmParams, min_depth_mm: float, max_depth_mm: float
) -> SgbmParams | None:
    """``params`` searching only the disparities of surfaces ``min_depth_mm..max_depth_mm``
    away that ``params`` searches (the count a multiple of 16); ``None`` when that is no
    fewer disparities."""
    low, count = disparity_range(calibration, min_depth_mm, max_depth_mm)
    top = params.min_disparity + params.num_disparities
    low = max(low, params.min_disparity)
    count = DISPARITY_STEP * math.ceil((min(low + count, top) - low) / DISPARITY_STEP)
    if count <= 0 or count >= params.num_disparities:
        return None
    return replace(params, min_disparity=min(low, top - count), num_disparities=count)


def sgbm_buffer_bytes(params: SgbmParams, image_size: tuple[int, int]) -> int:
    """Bytes of cost buffers StereoSGBM needs for ``params`` on images of ``image_size``."""
    width, height = image_size
    rows = 2 * height if params.mode in ("hh", "hh4") else SINGLE_PASS_ROWS
    return COST_BYTES * (width + params.num_disparities) * params.num_disparities * rows


def memory_bytes() -> int:
    """Physical memory of this machine (bytes)."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_disparity_range(params: SgbmParams, image_size: tuple[int, int]) -> None:
    """Refuse a disparity range SGBM cannot match on images of ``image_size`` (wider than the
    image, or cost buffers beyond half this machine's memory), naming the settings to change."""
    width = image_size[0]
    low, high = params.min_disparity, params.min_disparity + params.num_disparities - 1
    if params.num_disparities >= width or not -width < low < width:
        raise ReconError(
            f"disparity range {low}..{high} px does not fit the {width}-px wide "
            f"images (the range must be narrower than the image and start inside "
            f"it); set {RANGE_FLAGS}"
        )
    needed, limit = sgbm_buffer_bytes(params, image_size), memory_bytes() // 2
    if needed > limit:
        raise ReconError(
            f"disparity range {low}..{high} px with mode {params.mode!r} needs "
            f"{needed / 2**30:.1f} GiB of SGBM buffers, more than half of this "
            f"machine's {2 * limit / 2**30:.1f} GiB; narrow it with {RANGE_FLAGS} "
            f"or use mode sgbm_3way"
        )


def decoded_fraction(index: np.ndarray, row_step: int) -> float:
    """Share of pixels whose De Bruijn fringe index could be read (``index >= 0``) in an index
    whose blocks of ``row_step`` rows repeat their first row (as the decoder writes it): one row
    per block is counted, weighted by the block's rows."""
    readable = np.count_nonzero(index[::row_step] >= 0) * row_step
    short = -index.shape[0] % row_step  # rows the last block lacks
    if short:
        readable -= short * np.count_nonzero(index[-1] >= 0)
    return float(readable / max(index.size, 1))


def _fraction_text(values: np.ndarray) -> str:
    finite = values[np.isfinite(values)]
    return f"{np.mean(finite):.1%}" if finite.size else "n/a"


def _verified_share(reader: CloudReader) -> float:
    """Share of all points whose match the De Bruijn code confirmed."""
    flags = [reader.verified(i) for i in range(reader.n_frames)]
    total = sum(len(f) for f in flags)
    return sum(int(np.count_nonzero(f)) for f in flags) / max(total, 1)


def summary_line(reader: CloudReader) -> str:
    """One line: frames, density, decoded pattern, what verification did, disparity range."""
    n = reader.n_frames
    if not n:
        return f"{reader.path}: no frames"
    density = reader.frame_table("valid_fraction")
    counts = reader.frame_table("match_counts").astype(np.float64)
    sgbm = reader.attrs["sgbm"]
    low = int(sgbm.get("min_disparity", 0))
    parts = [
        f"{reader.path}: {n} frames",
        f"density {np.mean(density):.1%} (min {np.min(density):.1%})",
        f"pattern decoded {_fraction_text(reader.frame_table('decoded_fraction'))}",
    ]
    if np.all(counts[:, 1:] >= 0) and counts[:, 0].sum() > 0:
        total = counts[:, 0].sum()
        kept, corrected, rejected = (counts[:, k].sum() / total for k in (1, 2, 3))
        parts.append(
            f"matches kept {kept:.1%} / corrected {corrected:.1%} / rejected {rejected:.1%}"
        )
        parts.append(f"points verified {_verified_share(reader):.1%}")
    else:
        parts.append("no verification")
    parts.append(f"disparities {low}..{low + int(sgbm.get('num_disparities', 0)) - 1} px")
    return ", ".join(parts)


def frame_lines(reader: CloudReader, limit: int = 20) -> list[str]:
    """Per-frame quality rows (at most ``limit``, spread over the file) for ``vbfe inspect``."""
    n = reader.n_frames
    picks = np.unique(np.linspace(0, n - 1, min(n, limit)).astype(int)) if n else np.zeros(0, int)
    index = reader.frame_table("frame_index")
    density = reader.frame_table("valid_fraction")
    decoded = reader.frame_table("decoded_fraction")
    edge = reader.frame_table("edge_fraction")
    counts = reader.frame_table("match_counts")
    lines = ["  frame  density  decoded  at-edge    kept  corrected  rejected"]
    for i in picks:
        kept, corrected, rejected = (str(c) if c >= 0 else "-" for c in counts[i, 1:])
        lines.append(
            f"  {int(index[i]):5d}  {density[i]:7.1%}  "
            f"{'n/a' if not np.isfinite(decoded[i]) else f'{decoded[i]:.1%}':>7s}  "
            f"{edge[i]:7.1%}  {kept:>6s}  {corrected:>9s}  {rejected:>8s}"
        )
    return lines


def quality_warnings(reader: CloudReader, settings: ReconSettings) -> list[str]:
    """One-line warnings for a cloud file: a pattern too weak to verify most matches (they
    are then SGBM's, flagged unverified), matches piled up at the disparity range's edge."""
    warnings = []
    n = reader.n_frames
    decoded = reader.frame_table("decoded_fraction")
    weak = np.isfinite(decoded) & (decoded < settings.min_decoded_fraction)
    if weak.any():
        warnings.append(
            f"the De Bruijn pattern is readable on only {np.nanmedian(decoded[weak]):.2%} of the "
            f"pixels in {int(weak.sum())} of {n} frames (need {settings.min_decoded_fraction:.0%}"
            f"), so their matches are SGBM's alone, flagged unverified; is the projector on "
            f"and the pattern in view? For pairs without the pattern use --no-verify"
        )
    edge = reader.frame_table("edge_fraction")
    if n and np.nanmax(edge) > settings.max_edge_fraction:
        sgbm = reader.attrs["sgbm"]
        low = int(sgbm.get("min_disparity", 0))
        warnings.append(
            f"{np.nanmax(edge):.1%} of the matched pixels sit at the edge of the disparity range "
            f"{low}..{low + int(sgbm.get('num_disparities', 0)) - 1} px (worst frame): the "
            f"surface is nearer or farther than it covers; widen [recon] min_depth_mm/"
            f"max_depth_mm or set [sgbm] num_disparities"
        )
    return warnings
