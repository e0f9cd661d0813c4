"""``vbfe dataset DIR --report``: a page over the dataset (one row per session with its
verdicts, linking each session's own page) and every session's page, in one folder."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path

from vbfe.batch.manifest import SessionEntry
from vbfe.common.errors import SessionError
from vbfe.common.report import HtmlReport, Link

COLUMNS = (
    ("status", "status"),
    ("condition", "condition"),
    ("operator", "operator"),
    ("date_utc", "date (UTC)"),
    ("duration_s", "duration (s)"),
    ("frames", "frames"),
    ("frame_drops", "frame drops"),
    ("force_drops", "force drops"),
    ("sync_verdict", "sync"),
    ("calibration_hash", "calibration"),
    ("clouds", "clouds"),
)


def page_name(shown_path: str) -> str:
    """The file name of a session's page: its dataset path with separators flattened."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", shown_path.removesuffix(".h5")) + ".html"


def write_dataset_report(
    folder: str | Path,
    entries: Sequence[SessionEntry],
    out_dir: str | Path,
    relative_to: str | Path | None = None,
    on_session: Callable[[int, int], None] | None = None,
) -> Path:
    """Write ``out_dir/index.html`` and one page per readable session into ``out_dir``
    (created); ``entries`` as :func:`~vbfe.batch.manifest.scan_dataset` gave them for
    ``folder``, paths relative to ``relative_to`` (default ``folder``). Returns the index."""
    from vbfe.session_report import write_session_report

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for k, entry in enumerate(entries):
        name = page_name(entry.path)
        session = Path(relative_to if relative_to is not None else folder) / entry.path
        link: object = entry.path
        if not entry.status.startswith("unreadable"):
            try:
                write_session_report(session, out_dir / name)
                link = Link(entry.path, name)
            except SessionError as exc:
                entry.status = f"unreadable: {exc}"
        rows.append([link] + [_shown(getattr(entry, key)) for key, _ in COLUMNS])
        if on_session is not None:
            on_session(k + 1, len(entries))
    page = HtmlReport(f"Dataset {Path(folder).resolve().name}")
    unreadable = sum(e.status.startswith("unreadable") for e in entries)
    page.paragraph(
        f"{len(entries)} sessions under {Path(folder).resolve()}, {unreadable} "
        "unreadable; each name links to the session's page."
    )
    page.table(["session"] + [label for _, label in COLUMNS], rows)
    return page.write(out_dir / "index.html")


def _shown(value: object, width: int = 60) -> object:
    text = str(value)
    if not text:
        return "-"
    return value if len(text) <= width else text[: width - 1] + "…"
