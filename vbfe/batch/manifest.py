"""The dataset view: one row per session under a folder, and the manifest CSV that holds it.

A manifest is a CSV with a header row; ``path`` is relative to the manifest's folder when the
session lies below it (so a dataset folder can move, or be mounted elsewhere on a cluster).
``train``, ``evaluate``, ``reconstruct`` and ``verify-sync`` accept a manifest wherever they
accept session files.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from vbfe.acquire import SessionReader
from vbfe.acquire.session.inspect import inspect_session
from vbfe.common.errors import BatchError, SessionError
from vbfe.common.files import atomic_path
from vbfe.recon import SgbmParams
from vbfe.recon.freshness import clouds_status, text_hash

MANIFEST_SUFFIX = ".csv"
SIDECAR_SUFFIXES = (".clouds.h5", ".partial")


@dataclass
class SessionEntry:
    """What the dataset view shows of one session (``status`` is ``unreadable: …`` when the
    file could not be read; the other fields are then empty)."""

    path: str
    status: str = ""
    condition: str = ""
    operator: str = ""
    date_utc: str = ""
    duration_s: float | str = ""
    frames: int | str = ""
    frame_drops: int | str = ""
    force_samples: int | str = ""
    force_drops: int | str = ""
    sync_verdict: str = ""
    calibration_hash: str = ""
    clouds: str = ""


COLUMNS = [f.name for f in dataclasses.fields(SessionEntry)]


def find_sessions(folder: str | Path) -> list[Path]:
    """Every session file (``*.h5``, not a cloud sidecar) below ``folder``, sorted."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BatchError(f"dataset folder {folder} does not exist or is not a folder")
    return sorted(
        p for p in folder.rglob("*.h5") if p.is_file() and not p.name.endswith(SIDECAR_SUFFIXES)
    )


def _condition_text(conditions: dict) -> str:
    return ";".join(f"{k}={v}" for k, v in sorted(conditions.items()))


def describe_session(path: Path, shown_as: str, sgbm_params: SgbmParams) -> SessionEntry:
    """The dataset row of one session; an unreadable file gives a row that says so."""
    try:
        summary = inspect_session(path)
        with SessionReader(path) as reader:
            calibration = reader.calibration_yaml()
        clouds = str(clouds_status(path, sgbm_params))
    except SessionError as exc:
        return SessionEntry(path=shown_as, status=f"unreadable: {exc}")
    start = datetime.datetime.fromtimestamp(
        int(summary.attrs.get("start_utc_ns") or 0) / 1e9, datetime.timezone.utc
    )
    camera, force = summary.audits["camera"], summary.audits["force"]
    return SessionEntry(
        path=shown_as,
        status="not closed" if summary.truncated else "complete",
        condition=_condition_text(summary.metadata.get("conditions") or {}),
        operator=str(summary.metadata.get("operator") or ""),
        date_utc=f"{start:%Y-%m-%d %H:%M:%S}",
        duration_s=round(summary.duration_s, 3),
        frames=camera.stored,
        frame_drops=camera.dropped,
        force_samples=force.stored,
        force_drops=force.dropped,
        sync_verdict=str(summary.analysis.get("sync_verdict", "")),
        calibration_hash=text_hash(calibration),
        clouds=clouds,
    )


def _shown_path(path: Path, base: Path) -> str:
    try:
        return str(path.resolve().relative_to(base.resolve()))
    except ValueError:
        return str(path.resolve())


def scan_dataset(
    folder: str | Path, sgbm_params: SgbmParams | None = None, relative_to: str | Path | None = None
) -> list[SessionEntry]:
    """One row per session below ``folder``; paths relative to ``relative_to`` (the manifest's
    folder; default ``folder``) where possible."""
    base = Path(relative_to) if relative_to is not None else Path(folder)
    params = sgbm_params or SgbmParams()
    return [describe_session(p, _shown_path(p, base), params) for p in find_sessions(folder)]


def write_manifest(path: str | Path, entries: Iterable[SessionEntry]) -> Path:
    """Write the rows as a CSV manifest (to a temporary name, then renamed into place)."""
    path = Path(path)
    try:
        with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=COLUMNS)
            writer.writeheader()
            writer.writerows(dataclasses.asdict(e) for e in entries)
    except OSError as exc:
        raise BatchError(f"cannot write manifest {path}: {exc.strerror or exc}") from None
    return path


def read_manifest(path: str | Path) -> list[Path]:
    """The session paths a manifest lists (resolved against the manifest's folder)."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise BatchError(f"cannot read manifest {path}: {exc}") from None
    if not rows or "path" not in rows[0]:
        raise BatchError(
            f"manifest {path} has no 'path' column or no rows; write one with "
            f"'vbfe dataset DIR --manifest {path.name}'"
        )
    return [(path.parent / row["path"]) for row in rows if row["path"]]


def expand_sessions(inputs: Sequence[str | Path]) -> list[Path]:
    """Session files from a mix of session paths and manifests (``*.csv``), in order."""
    sessions: list[Path] = []
    for item in inputs:
        item = Path(item)
        sessions.extend(read_manifest(item) if item.suffix == MANIFEST_SUFFIX else [item])
    return sessions
