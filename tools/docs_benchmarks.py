"""The manual's benchmark page, generated: each benchmark's purpose (its docstring's first
paragraph) and what its latest kept run printed (``python -m benchmarks.logbook NAME``), with
the date, commit, machine and load it ran under. mkdocs calls :func:`on_page_markdown`
(``hooks`` in mkdocs.yml) for the page that holds the marker."""

from __future__ import annotations

import ast
import json
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
RUNS = ROOT / "benchmarks" / "runs"
MARKER = "<!-- generated: benchmarks -->"


def _purpose(script: Path) -> str:
    doc = ast.get_docstring(ast.parse(script.read_text())) or ""
    return " ".join(doc.split("\n\n")[0].split())


def latest_run(name: str, runs: Path = RUNS) -> dict[str, Any] | None:
    """The newest kept run of benchmark ``name`` (None when none was kept)."""
    kept = sorted((runs / name).glob("*.json"))
    return json.loads(kept[-1].read_text()) if kept else None


def benchmarks_markdown(runs: Path = RUNS) -> str:
    """A section per benchmark: purpose, command, and the latest run's output as printed."""
    out = []
    for script in sorted((ROOT / "benchmarks").glob("bench_*.py")):
        name = script.stem
        out += [f"## `{name}`", "", _purpose(script), ""]
        run = latest_run(name, runs)
        if run is None:
            out += [f"No kept run yet: `python -m benchmarks.logbook {name}`.", ""]
            continue
        m, load = run["machine"], run["load_average"]
        out += [
            f"`{run['command']}`, {run['started_utc']}, commit `{run['commit']}`, "
            f"{m['cores']} cores ({m['cpu']}), load average {load['min']:.1f}–{load['max']:.1f}, "
            f"{run['wall_s']:.0f} s:",
            "",
            "```text",
            *run["output"],
            "```",
            "",
        ]
    return "\n".join(out)


def on_page_markdown(markdown: str, **_: Any) -> str:
    """mkdocs hook: the generated page in place of its marker."""
    return markdown.replace(MARKER, benchmarks_markdown()) if MARKER in markdown else markdown
