"""Evaluation outputs: metrics.json, a Markdown and an HTML table, force-versus-time plots.

Plots are drawn with matplotlib's Agg canvas directly (no pyplot state, no display needed).
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from vbfe.common.files import save_figure, write_bytes_atomic
from vbfe.common.report import HtmlReport

METHOD_LABELS = {
    "pointnet": "PointNet",
    "temporal": "Temporal PointNet",
    "mean": "Mean predictor",
    "linear_displacement": "Linear on displacement",
    "hooke": "Hooke (fitted k̂)",
    "ridge_height_map": "Ridge on depth-change thumbnail",
    "cnn_depth_change": "CNN on depth-change image",
    "ensemble_cnn_hooke": "Mean of CNN and Hooke",
    "hooke_texture_3d": "Hooke on texture 3D displacement",
    "mlp_displacement_history": "MLP on displacement history",
}


def write_json(path: Path, data: dict[str, Any]) -> Path:
    """Write ``data`` as indented JSON."""
    return write_bytes_atomic(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def metric_rows(metrics: dict[str, dict[str, Any]], key: str) -> tuple[list[str], list[list[str]]]:
    """Header and rows (overall with its 95 % interval, then each condition) of ``MAE (σ)``,
    ``RMSE`` or (``key="interval"``) the prediction interval's coverage and mean width per
    method (``–``: the method has no interval)."""
    methods = list(metrics)
    header = ["Condition", "Frames", *(METHOD_LABELS.get(m, m) for m in methods)]
    first = metrics[methods[0]]
    groups = [("all", first["overall"]), *first["per_condition"].items()]
    rows = []
    for label, stats in groups:
        cells = []
        for m in methods:
            s = metrics[m]["overall"] if label == "all" else metrics[m]["per_condition"][label]
            if key == "interval":
                cells.append(
                    f"{100 * s['interval_coverage']:.1f} % / {s['interval_width_n']:.3f}"
                    if "interval_coverage" in s
                    else "–"
                )
                continue
            cell = (
                f"{s['mae_n']:.3f} ({s['sd_abs_error_n']:.3f})"
                if key == "mae"
                else f"{s['rmse_n']:.3f}"
            )
            interval = s.get(f"{key}_ci95_n")
            cells.append(cell + (f" [{interval[0]:.3f}, {interval[1]:.3f}]" if interval else ""))
        rows.append([label, str(stats["n_frames"]), *cells])
    return header, rows


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def write_tables(
    out_dir: Path, metrics: dict[str, dict[str, Any]], notes: Sequence[str], plots: Sequence[Path]
) -> tuple[Path, Path]:
    """Write report.md and report.html: MAE (σ) and RMSE tables (newtons) plus notes and plots."""
    sections = [
        ("MAE (σ of absolute error) [95 % interval], N", metric_rows(metrics, "mae")),
        ("RMSE [95 % interval], N", metric_rows(metrics, "rmse")),
        (
            "Prediction intervals: coverage of the measured force / mean width, N",
            metric_rows(metrics, "interval"),
        ),
    ]
    md = ["# Force estimation report", ""]
    page = HtmlReport("Force estimation report")
    for title, (header, rows) in sections:
        md += [f"## {title}", "", markdown_table(header, rows), ""]
        page.heading(title)
        page.table(header, rows)
    md += ["## Notes", "", *(f"- {n}" for n in notes), "", "## Plots", ""]
    md += [f"![{p.stem}]({p.name})" for p in plots]
    page.heading("Notes")
    page.bullets(notes)
    page.heading("Plots")
    for plot in plots:
        page.image(plot, plot.stem, plot.parent)
    md_path = out_dir / "report.md"
    write_bytes_atomic(md_path, "\n".join(md) + "\n")
    return md_path, page.write(out_dir / "report.html")


def _plotted(force_n: np.ndarray) -> np.ndarray:
    """One number per frame: the value itself (one output, signed), else the vector's length."""
    force = np.asarray(force_n).reshape(len(force_n), -1)
    return force[:, 0] if force.shape[1] == 1 else np.linalg.norm(force, axis=1)


def plot_session(
    path: Path,
    title: str,
    times_ns: np.ndarray,
    measured_n: np.ndarray,
    predictions: dict[str, np.ndarray],
    ylabel: str = "|F| (N)",
    highlight: str = "pointnet",
    flagged: np.ndarray | None = None,
) -> Path:
    """Force versus time (``ylabel``: what one number per frame is): measured and every
    method's prediction (``predictions``; ``<method>_lo``/``_hi`` its interval), ``highlight``
    drawn solid with its interval as a band, frames ``flagged`` outside the training data
    marked, as a PNG."""
    fig = Figure(figsize=(8, 4), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    t_s = (np.asarray(times_ns) - times_ns[0]) / 1e9 if len(times_ns) else np.zeros(0)
    ax.plot(t_s, _plotted(measured_n), color="black", lw=2, label="measured (trocar)")
    methods = [m for m in predictions if not m.endswith(("_lo", "_hi"))]
    for method in methods:
        style = {"lw": 1.5} if method == highlight else {"lw": 1, "ls": "--"}
        line = ax.plot(
            t_s, _plotted(predictions[method]), label=METHOD_LABELS.get(method, method), **style
        )
        if method == highlight and f"{method}_lo" in predictions:
            lo, hi = predictions[f"{method}_lo"], predictions[f"{method}_hi"]
            if lo.shape[-1] == 1:  # one output: its band (three: the vector has no band)
                ax.fill_between(
                    t_s,
                    lo[:, 0],
                    hi[:, 0],
                    color=line[0].get_color(),
                    alpha=0.2,
                    lw=0,
                    label="prediction interval",
                )
    if flagged is not None and np.any(flagged):
        ax.plot(
            t_s[flagged],
            _plotted(predictions[highlight])[flagged],
            "x",
            color="red",
            ms=4,
            label="outside the training data",
        )
    ax.set_xlabel("time (s)")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_scatter(
    path: Path,
    measured_n: np.ndarray,
    predicted_n: np.ndarray,
    labels: Sequence[str],
    axis: str = "|F| (N)",
    method: str = "pointnet",
) -> Path:
    """Predicted versus measured force (``axis``: what is plotted), one colour per condition,
    with the identity line."""
    fig = Figure(figsize=(5, 5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    measured, predicted = _plotted(measured_n), _plotted(predicted_n)
    label_of = np.asarray(labels)
    for label in sorted(set(label_of)):
        mask = label_of == label
        ax.scatter(measured[mask], predicted[mask], s=4, alpha=0.5, label=label)
    low = float(min(measured.min(), predicted.min(), 0.0))
    top = float(max(measured.max(), predicted.max(), 1e-3))
    ax.plot([low, top], [low, top], "k--", lw=1)
    ax.set_xlabel(f"measured {axis}")
    ax.set_ylabel(f"{METHOD_LABELS.get(method, method)} {axis}")
    ax.legend(fontsize=7, markerscale=3)
    fig.tight_layout()
    return save_figure(fig, path)


def safe_stem(name: str) -> str:
    """A file-name-safe stem for a session name or path."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(name).name.removesuffix(".h5"))[:80] or "session"
