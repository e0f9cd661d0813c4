"""Adding to a closed session: the calibration, analysis results, the live estimate stream."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py

from vbfe.acquire.session.estimates import EstimateStream, finish_estimates, write_estimates
from vbfe.acquire.session.reader import check_session, open_session_file
from vbfe.common.files import WriterLock


def store_calibration(session_path: str | Path, yaml_text: str) -> None:
    """Put (or replace) the calibration YAML text of an existing session."""
    store_analysis(session_path, {}, calibration_yaml=yaml_text)


def store_analysis(
    session_path: str | Path, values: dict[str, Any], calibration_yaml: str | None = None
) -> None:
    """Add attributes to ``/analysis`` (and optionally the calibration) of a closed session
    (refused, naming the process, while another one writes it)."""
    with WriterLock(session_path), open_session_file(session_path, "r+")[0] as f:
        check_session(f, Path(session_path))
        if calibration_yaml is not None:
            if "calibration_yaml" in f:
                del f["calibration_yaml"]
            f.create_dataset("calibration_yaml", data=calibration_yaml, dtype=h5py.string_dtype())
        if values:
            f.require_group("analysis").attrs.update(values)


def store_estimates(session_path: str | Path, stream: EstimateStream) -> None:
    """Write (or replace) the live estimate stream of a closed session."""
    with WriterLock(session_path), open_session_file(session_path, "r+")[0] as f:
        check_session(f, Path(session_path))
        write_estimates(f, stream)


def store_estimate_counts(session_path: str | Path, counts: dict[str, Any]) -> None:
    """Add a live run's counts to the ``/estimate`` stream it wrote into a closed session."""
    with WriterLock(session_path), open_session_file(session_path, "r+")[0] as f:
        check_session(f, Path(session_path))
        finish_estimates(f, counts)
