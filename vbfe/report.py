"""A small static HTML report: headings, paragraphs, tables and images, nothing to install."""

from __future__ import annotations

import html
import os
from collections.abc import Sequence
from pathlib import Path

from vbfe.files import write_bytes_atomic

_STYLE = """
body { font-family: sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }
table { border-collapse: collapse; margin: 0.8em 0; }
th, td { border: 1px solid #bbb; padding: 4px 10px; text-align: right; }
th { background: #eee; } td:first-child, th:first-child { text-align: left; }
img { max-width: 100%; border: 1px solid #ddd; margin: 0.4em 0; }
.pass { color: #070; font-weight: bold; } .fail { color: #a00; font-weight: bold; }
figure { margin: 1em 0; } figcaption { color: #555; font-size: 90%; }
"""


def _cell(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return html.escape(str(value))


class HtmlReport:
    """Collects report parts in order and writes one self-contained ``index.html``."""

    def __init__(self, title: str) -> None:
        self.title = title
        self._parts: list[str] = []

    def heading(self, text: str, level: int = 2) -> None:
        """A section heading."""
        self._parts.append(f"<h{level}>{html.escape(text)}</h{level}>")

    def paragraph(self, text: str) -> None:
        """A paragraph of plain text."""
        self._parts.append(f"<p>{html.escape(text)}</p>")

    def verdict(self, label: str, passed: bool) -> None:
        """A PASS/FAIL line."""
        cls, word = ("pass", "PASS") if passed else ("fail", "FAIL")
        self._parts.append(f'<p>{html.escape(label)}: <span class="{cls}">{word}</span></p>')

    def table(self, header: Sequence[str], rows: Sequence[Sequence[object]]) -> None:
        """A table; floats are shown with four significant digits."""
        head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{_cell(v)}</td>" for v in row) + "</tr>"
                       for row in rows)
        self._parts.append(f"<table><tr>{head}</tr>{body}</table>")

    def image(self, path: str | Path, caption: str, relative_to: str | Path) -> None:
        """An image, linked relative to the report's folder."""
        src = html.escape(Path(os.path.relpath(path, relative_to)).as_posix())
        self._parts.append(f'<figure><img src="{src}" alt="{html.escape(caption)}">'
                           f"<figcaption>{html.escape(caption)}</figcaption></figure>")

    def write(self, path: str | Path) -> Path:
        """Write the report as HTML and return its path."""
        path = Path(path)
        body = "\n".join(self._parts)
        return write_bytes_atomic(
            path, f"<!doctype html><html><head><meta charset='utf-8'><title>"
            f"{html.escape(self.title)}</title><style>{_STYLE}</style></head><body>"
            f"<h1>{html.escape(self.title)}</h1>\n{body}\n</body></html>")
