"""The one HTML page writer of vbfe: headings, paragraphs, lists, tables, images (linked, or
inline as base64 so a page is one self-contained file), links; nothing to install."""

from __future__ import annotations

import base64
import html
import io
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vbfe.common.files import write_bytes_atomic

_STYLE = """
body { font-family: sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }
table { border-collapse: collapse; margin: 0.8em 0; }
th, td { border: 1px solid #bbb; padding: 4px 10px; text-align: right; }
th { background: #eee; } td:first-child, th:first-child { text-align: left; }
img { max-width: 100%; border: 1px solid #ddd; margin: 0.4em 0; }
.pass { color: #070; font-weight: bold; } .fail { color: #a00; font-weight: bold; }
.warn { color: #a60; font-weight: bold; }
figure { margin: 1em 0; } figcaption { color: #555; font-size: 90%; }
.strip { display: flex; flex-wrap: wrap; gap: 6px; }
.strip figure { margin: 0; } .strip img { margin: 0; }
"""
_VERDICT_CLASS = {"PASS": "pass", "FAIL": "fail", "INCONCLUSIVE": "warn"}


@dataclass(frozen=True)
class Link:
    """A table cell (or paragraph part) that links to ``href``."""

    text: str
    href: str


def _cell(value: object) -> str:
    if isinstance(value, Link):
        return f'<a href="{html.escape(value.href)}">{html.escape(value.text)}</a>'
    if isinstance(value, float):
        return f"{value:.4g}"
    text = html.escape(str(value))
    cls = _VERDICT_CLASS.get(str(value).upper())
    return f'<span class="{cls}">{text}</span>' if cls else text


def png_bytes(figure: Any, dpi: int = 90) -> bytes:
    """A matplotlib figure as PNG bytes."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


class HtmlReport:
    """Collects report parts in order and writes one HTML page."""

    def __init__(self, title: str) -> None:
        self.title = title
        self._parts: list[str] = []

    def heading(self, text: str, level: int = 2) -> None:
        """A section heading."""
        self._parts.append(f"<h{level}>{html.escape(text)}</h{level}>")

    def paragraph(self, text: str) -> None:
        """A paragraph of plain text."""
        self._parts.append(f"<p>{html.escape(text)}</p>")

    def bullets(self, items: Sequence[str]) -> None:
        """A bulleted list of plain text."""
        self._parts.append("<ul>" + "".join(f"<li>{html.escape(i)}</li>" for i in items) + "</ul>")

    def verdict(self, label: str, passed: bool) -> None:
        """A PASS/FAIL line."""
        cls, word = ("pass", "PASS") if passed else ("fail", "FAIL")
        self._parts.append(f'<p>{html.escape(label)}: <span class="{cls}">{word}</span></p>')

    def table(self, header: Sequence[str], rows: Sequence[Sequence[object]]) -> None:
        """A table (no header row when every header is empty); floats are shown with four
        significant digits, :class:`Link` cells link, PASS / FAIL / INCONCLUSIVE are coloured."""
        head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join(
            "<tr>" + "".join(f"<td>{_cell(v)}</td>" for v in row) + "</tr>" for row in rows
        )
        head = f"<tr>{head}</tr>" if any(header) else ""  # all empty: a key-value table
        self._parts.append(f"<table>{head}{body}</table>")

    def image(self, path: str | Path, caption: str, relative_to: str | Path) -> None:
        """An image file, linked relative to the report's folder."""
        src = Path(os.path.relpath(path, relative_to)).as_posix()
        self._figure(src, caption)

    def inline_image(self, data: bytes, caption: str, mime: str = "image/png") -> None:
        """Image bytes embedded in the page (base64)."""
        self._figure(_data_uri(data, mime), caption)

    def inline_strip(self, images: Sequence[tuple[bytes, str]], mime: str = "image/jpeg") -> None:
        """Small images side by side, each with its caption, embedded in the page."""
        self._parts.append(
            '<div class="strip">'
            + "".join(
                f'<figure><img src="{_data_uri(data, mime)}" alt="{html.escape(caption)}">'
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
                for data, caption in images
            )
            + "</div>"
        )

    def _figure(self, src: str, caption: str) -> None:
        self._parts.append(
            f'<figure><img src="{html.escape(src)}" alt="{html.escape(caption)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )

    def html(self) -> str:
        """The page as HTML text."""
        body = "\n".join(self._parts)
        return (
            f"<!doctype html><html><head><meta charset='utf-8'><title>"
            f"{html.escape(self.title)}</title><style>{_STYLE}</style></head><body>"
            f"<h1>{html.escape(self.title)}</h1>\n{body}\n</body></html>"
        )

    def write(self, path: str | Path) -> Path:
        """Write the page (to a temporary name, renamed when complete) and return its path."""
        return write_bytes_atomic(path, self.html())
