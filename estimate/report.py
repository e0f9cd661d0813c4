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

from vbfe.report import HtmlReport

METHOD_LABELS = {"pointnet": "PointNet", "temporal": "Temporal PointNet",
                 "mean": "Mean predictor", "linear_displacement": "Linear on displacement",
                 "hooke": "Hooke (fitted k̂)", "ridge_height_map": "Ridge on height map",
                 "mlp_displacement_history": "MLP on displacement history"}


def write_json(path: Path, data: dict[str, Any]) -> Path:
    """Write ``data`` as indented JSON."""
    path.write_text(json.dumps(data, indent=2, sort_keys=False) + "\n", encoding="utf-8")
    return path


def metric_rows(metrics: dict[str, dict[str, Any]], key: str) -> tuple[list[str], list[list[str]]]:
    """Header and rows (overall, then each condition) of ``MAE (σ)`` or ``RMSE`` per method."""
    methods = list(metrics)
    header = ["Condition", "Frames", *(METHOD_LABELS.get(m, m) for m in methods)]
    first = metrics[methods[0]]
    groups = [("all", first["overall"]), *first["per_condition"].items()]
    rows = []
    for label, stats in groups:
        cells = []
        for m in methods:
            s = metrics[m]["overall"] if label == "all" else metrics[m]["per_condition"][label]
            cells.append(f"{s['mae_n']:.3f} ({s['sd_abs_error_n']:.3f})" if key == "mae"
                         else f"{s['rmse_n']:.3f}")
        rows.append([label, str(stats["n_frames"]), *cells])
    return header, rows


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def write_tables(out_dir: Path, metrics: dict[str, dict[str, Any]], notes: Sequence[str],
                 plots: Sequence[Path]) -> tuple[Path, Path]:
    """Write report.md and report.html: MAE (σ) and RMSE tables (newtons) plus notes and plots."""
    sections = [("MAE (σ of absolute error), N", metric_rows(metrics, "mae")),
                ("RMSE, N", metric_rows(metrics, "rmse"))]
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
    md_path.write_text("\n".join(md) + "\n", encoding="utf-8")
    return md_path, page.write(out_dir / "report.html")


def _magnitude(force_n: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.asarray(force_n).reshape(len(force_n), -1), axis=1)


def plot_session(path: Path, title: str, times_ns: np.ndarray, measured_n: np.ndarray,
                 predictions: dict[str, np.ndarray]) -> Path:
    """Force magnitude versus time: measured and every method's prediction, as a PNG."""
    fig = Figure(figsize=(8, 4), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    t_s = (np.asarray(times_ns) - times_ns[0]) / 1e9
    ax.plot(t_s, _magnitude(measured_n), color="black", lw=2, label="measured (trocar)")
    for method, force in predictions.items():
        style = {"lw": 1.5} if method == "pointnet" else {"lw": 1, "ls": "--"}
        ax.plot(t_s, _magnitude(force), label=METHOD_LABELS.get(method, method), **style)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("|F| (N)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    return path


def plot_scatter(path: Path, measured_n: np.ndarray, predicted_n: np.ndarray,
                 labels: Sequence[str]) -> Path:
    """PointNet-predicted versus measured |F|, one colour per condition, with the identity line."""
    fig = Figure(figsize=(5, 5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    measured, predicted = _magnitude(measured_n), _magnitude(predicted_n)
    labels = np.asarray(labels)
    for label in sorted(set(labels)):
        mask = labels == label
        ax.scatter(measured[mask], predicted[mask], s=4, alpha=0.5, label=label)
    top = float(max(measured.max(), predicted.max(), 1e-3))
    ax.plot([0, top], [0, top], "k--", lw=1)
    ax.set_xlabel("measured |F| (N)")
    ax.set_ylabel("PointNet |F| (N)")
    ax.legend(fontsize=7, markerscale=3)
    fig.tight_layout()
    fig.savefig(path)
    return path


def safe_stem(name: str) -> str:
    """A file-name-safe stem for a session name or path."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(name).name.removesuffix(".h5"))[:80] or "session"
