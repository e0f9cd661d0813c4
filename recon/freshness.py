"""Whether a session's point-cloud sidecar is missing, stale or current."""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass
from pathlib import Path

from vbfe.acquire import SessionReader
from vbfe.calib.calibration import Calibration
from vbfe.common.errors import ReconError
from vbfe.recon.clouds import CloudReader, session_fingerprint, sidecar_path
from vbfe.recon.matching import SgbmParams
from vbfe.recon.quality import ReconSettings, params_for


@dataclass(frozen=True)
class CloudsStatus:
    """``state`` is ``"missing"``, ``"stale"`` or ``"current"``; ``reason`` says why stale."""

    state: str
    reason: str = ""

    def __str__(self) -> str:
        return f"{self.state} ({self.reason})" if self.reason else self.state


def text_hash(text: str | None) -> str:
    """Short SHA-256 of a text (a calibration YAML), ``""`` for none."""
    return hashlib.sha256(text.encode()).hexdigest()[:12] if text else ""


def fingerprint_of(reader: SessionReader) -> str:
    """The fingerprint a sidecar of this open session carries."""
    return session_fingerprint(
        int(reader.attrs.get("start_utc_ns") or 0), reader.stream_times("camera")
    )


def clouds_status(
    session_path: str | Path,
    sgbm_params: SgbmParams,
    verify: bool = True,
    calibration_yaml: str | None = None,
    settings: ReconSettings | None = None,
) -> CloudsStatus:
    """Compare ``<session>.clouds.h5`` with the session, the calibration (default: the one
    stored in the session) and the matcher settings that would be used now (a range derived
    from the geometry is derived again from ``settings``, the ``[recon]`` table)."""
    out = sidecar_path(session_path)
    if not out.exists():
        return CloudsStatus("missing")
    try:
        with CloudReader(out) as clouds:
            attrs, used_calibration = clouds.attrs, clouds.calibration_yaml()
            fingerprint = clouds.session_fingerprint
    except ReconError:
        return CloudsStatus("stale", "incomplete or unreadable cloud file")
    with SessionReader(session_path) as reader:
        if fingerprint != fingerprint_of(reader):
            return CloudsStatus("stale", "computed from another recording")
        if calibration_yaml is None:
            calibration_yaml = reader.calibration_yaml()
    if calibration_yaml is not None and text_hash(calibration_yaml) != text_hash(used_calibration):
        return CloudsStatus("stale", "calibration changed")
    calibration = Calibration.from_yaml_text(calibration_yaml or used_calibration)
    resolved = params_for(calibration, sgbm_params, settings or ReconSettings())
    if attrs["sgbm"] != dataclasses.asdict(resolved) or bool(attrs.get("verify")) != verify:
        return CloudsStatus("stale", "matcher settings changed")
    return CloudsStatus("current")
