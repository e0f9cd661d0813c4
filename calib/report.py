"""Calibration report: a PNG figure (per-view error, corner coverage, rectified pair with
epipolar lines) and a small HTML page with the numbers."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vbfe.calib.calibration import Calibration
from vbfe.calib.corner_choice import from_rows
from vbfe.calib.corner_choice import summary_rows as corner_rows
from vbfe.calib.stereo import StereoResult
from vbfe.calib.uncertainty import UncertaintyMap
from vbfe.calib.views import ViewSet
from vbfe.common.files import save_figure
from vbfe.common.report import HtmlReport


def epipolar_overlay(
    calibration: Calibration, left: np.ndarray, right: np.ndarray, spacing_px: int = 24
) -> np.ndarray:
    """The rectified pair side by side with horizontal epipolar lines every ``spacing_px``."""
    rl, rr = calibration.rectify(left, right)
    pair = np.hstack([rl, rr])
    for y in range(spacing_px // 2, pair.shape[0], spacing_px):
        cv2.line(pair, (0, y), (pair.shape[1] - 1, y), (0, 200, 0), 1, cv2.LINE_AA)
    return pair


GATE_COLUMNS = ("gate", "measured", "limit", "verdict")


def gate_lines(calibration: Calibration) -> list[str]:
    """The gate table stored with a calibration as aligned text lines (header first)."""
    rows = [list(GATE_COLUMNS), *calibration.info.get("gates", [])]
    if len(rows) == 1:
        return []
    widths = [max(len(str(r[k])) for r in rows) for k in range(len(GATE_COLUMNS))]
    return [
        "  ".join(f"{str(v):<{w}}" for v, w in zip(r, widths, strict=True)).rstrip() for r in rows
    ]


def summary_rows(calibration: Calibration) -> list[tuple[str, str]]:
    """(label, value) rows describing a calibration, for reports and the CLI."""
    info = calibration.info
    rows = [
        ("image size", f"{calibration.image_size[0]} x {calibration.image_size[1]} px"),
        (
            "f (rectified)",
            f"{calibration.f:.2f} px"
            + (f" (fx), {calibration.fy:.2f} px (fy)" if calibration.fy != calibration.f else ""),
        ),
        (
            "cx, cy (rectified)",
            f"{calibration.cx:.2f}, {calibration.cy:.2f} px"
            + (f"; doffs {calibration.doffs:.2f} px" if calibration.doffs else ""),
        ),
        ("B", f"{calibration.B * 1e3:.4f} mm"),
    ]
    if np.isfinite(calibration.rms_stereo_px):
        rows.append(
            (
                "RMS left / right / stereo",
                f"{calibration.rms_left_px:.3f} / "
                f"{calibration.rms_right_px:.3f} / {calibration.rms_stereo_px:.3f} px",
            )
        )
    if "sigma_B_m" in info:
        rows += [
            ("σ(B)", f"{info['sigma_B_m'] * 1e3:.4f} mm"),
            (
                "σ(fx) left / right",
                f"{info['std_left']['fx']:.3f} / {info['std_right']['fx']:.3f} px",
            ),
            ("epipolar RMS", f"{info['epipolar_rms_px']:.3f} px"),
            (
                f"depth σ at {info['working_distance_m'] * 1e3:.0f} mm",
                f"{info['depth_sigma_at_working_distance_m'] * 1e3:.3f} mm (calibration) + "
                f"{info['depth_per_px_disparity_at_working_distance_m'] * 1e3:.3f} mm per px "
                "of disparity error",
            ),
        ]
    if "uncertainty" in info:
        rows.append(("uncertainty", info["uncertainty"]["summary"]))
    rows += corner_rows(from_rows(info.get("corners", [])))
    if "weakly_determined" in info:
        rows.append(("note", info["weakly_determined"]))
    if calibration.K_proj is not None:  # has_projector
        rows += [
            ("projector f", f"{calibration.K_proj[0, 0]:.2f} px"),
            ("projector RMS", f"{calibration.rms_projector_px:.3f} px"),
        ]
    return rows


def _uncertainty_figure(umap: UncertaintyMap, size: tuple[int, int], out_stem: Path) -> Path:
    """``<stem>_uncertainty.png``: the depth σ map and the board coverage per region."""
    from matplotlib import pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.5))
    shown = ax.imshow(
        umap.depth_sigma_m * 1e3,
        extent=(0, size[0], size[1], 0),
        interpolation="bilinear",
        cmap="viridis",
    )
    fig.colorbar(shown, ax=ax, label=f"depth σ at {umap.working_distance_m * 1e3:.0f} mm (mm)")
    ax.set_title("depth uncertainty over the left image")
    cover = bx.imshow(umap.coverage, extent=(0, size[0], size[1], 0), cmap="Greens", vmin=0)
    for (r, c), n in np.ndenumerate(umap.coverage):
        bx.text(
            (c + 0.5) * size[0] / umap.coverage.shape[1],
            (r + 0.5) * size[1] / umap.coverage.shape[0],
            str(n),
            ha="center",
            va="center",
            color="red" if n == 0 else "black",
        )
    fig.colorbar(cover, ax=bx, label="views with board corners")
    bx.set_title("board coverage per region (left eye)")
    fig.tight_layout()
    png = out_stem.parent / f"{out_stem.name}_uncertainty.png"
    fig.savefig(png, dpi=90)
    plt.close(fig)
    return png


def write_report(result: StereoResult, views: ViewSet, out_stem: str | Path) -> tuple[Path, Path]:
    """Write ``<stem>.png`` and ``<stem>.html``; returns both paths."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    out_stem = Path(out_stem)
    out_stem.parent.mkdir(parents=True, exist_ok=True)
    cal = result.calibration
    per_view = cal.per_view_rms_px
    assert per_view is not None  # a fresh calibration has it
    fig, axes = plt.subplots(2, 2, figsize=(12, 8))
    ax = axes[0, 0]
    x = np.arange(len(result.names))
    for k, label in enumerate(("left", "right", "stereo")):
        ax.bar(x + (k - 1) * 0.27, per_view[:, k], width=0.27, label=label)
    ax.set_xticks(x, result.names, rotation=90, fontsize=7)
    ax.set_ylabel("RMS reprojection error (px)")
    ax.set_title("per-view error")
    ax.legend()
    w, h = cal.image_size
    for ax, fit, eye in ((axes[0, 1], result.left, "left"), (axes[1, 0], result.right, "right")):
        for det in fit.detections:
            ax.plot(det.corners[:, 0], det.corners[:, 1], ".", ms=2)
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(f"corner coverage, {eye} ({sum(map(len, fit.detections))} corners)")
    index = views.names.index(result.names[0])
    overlay = epipolar_overlay(cal, *views.pairs[index])
    axes[1, 1].imshow(cv2.cvtColor(overlay, cv2.COLOR_BGR2RGB))
    axes[1, 1].set_title(f"rectified {result.names[0]} with epipolar lines")
    axes[1, 1].set_axis_off()
    fig.tight_layout()
    png = out_stem.with_suffix(".png")
    try:
        save_figure(fig, png, dpi=90)
    finally:
        plt.close(fig)

    report = HtmlReport("Stereo calibration")
    report.table(["quantity", "value"], summary_rows(cal))
    report.heading("Sanity gates")
    report.table(list(GATE_COLUMNS), cal.info.get("gates", []))
    report.image(png, "per-view error, corner coverage, rectified pair", out_stem.parent)
    if result.uncertainty is not None:
        report.heading("Uncertainty at the working distance")
        report.paragraph(result.uncertainty.summary())
        report.image(
            _uncertainty_figure(result.uncertainty, cal.image_size, out_stem),
            "depth σ over the left image; board views per image region",
            out_stem.parent,
        )
    report.heading("Corners per view")
    report.paragraph(
        "Each view and eye keeps the refinement whose corners fit the board best (RMS of a "
        "per-view pose fit with the camera's intrinsics); the edge width (10-90 % rise) says "
        "how blurred the board is."
    )
    report.table(
        ["view", "camera", "detector", "refinement kept", "edge width (px)", "residual (px)"],
        [
            (c.view, c.camera, c.finder, c.method, f"{c.edge_width_px:.2f}", f"{c.residual_px:.3f}")
            for c in from_rows(cal.info.get("corners", []))
        ],
    )
    report.heading("Dropped views")
    report.table(["view", "why"], sorted(result.dropped.items()))
    report.heading("Desynchronised views (right image shifted against left)")
    report.table(
        ["view", "dx (px)", "dy (px)"], [(k, dx, dy) for k, (dx, dy) in result.desync.items()]
    )
    rejected = cal.info.get("rejected_corners", [])
    report.heading(f"Rejected outlier corners ({len(rejected)})")
    report.table(["view", "camera", "corner id", "residual (px)"], rejected)
    return png, report.write(out_stem.with_suffix(".html"))
