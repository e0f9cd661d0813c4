"""The per-session tasks of a batch: picklable callables that write only their own outputs."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2

from vbfe.acquire import SessionReader
from vbfe.acquire.sync.check import SYNC_ESTIMATOR, SyncLimits, verify_sync
from vbfe.acquire.sync.protocol import ProtocolSettings
from vbfe.common.errors import BatchError
from vbfe.common.files import check_outputs
from vbfe.recon import CloudReader, SgbmParams, reconstruct_session, sidecar_path
from vbfe.recon.freshness import clouds_status
from vbfe.recon.quality import ReconSettings, summary_line


@dataclass(frozen=True)
class ReconstructTask:
    """Reconstruct one session into its sidecar; skip it when the sidecar is current."""

    sgbm: dict[str, Any] = field(default_factory=dict)
    verify: bool = True
    settings: dict[str, float] = field(default_factory=dict)  # the [recon] table
    calibration: str | None = None  # a YAML path; None: the one stored in the session
    overwrite: bool = False  # rebuild even a current sidecar, replace a stale one
    threads: int = 1  # OpenCV threads in this task's process

    def __call__(self, session: str) -> dict[str, Any]:
        params, settings = SgbmParams(**self.sgbm), ReconSettings(**self.settings)
        calibration_yaml = Path(self.calibration).read_text() if self.calibration else None
        status = clouds_status(session, params, self.verify, calibration_yaml, settings)
        out = sidecar_path(session)
        if status.state == "current" and not self.overwrite:
            return {"action": "up to date", "out": str(out)}
        if status.state == "stale" and not self.overwrite:
            raise BatchError(f"{out} is {status}; pass --overwrite to rebuild it")
        cv2.setNumThreads(self.threads)
        reconstruct_session(
            session,
            calibration=self.calibration,
            workers=1,
            sgbm_params=params,
            verify=self.verify,
            settings=settings,
        )
        with CloudReader(out) as clouds:
            return {
                "action": "reconstructed",
                "out": str(out),
                "frames": clouds.n_frames,
                "summary": summary_line(clouds),
            }


@dataclass(frozen=True)
class VerifySyncTask:
    """Check one session's synchronisation; skip it when it already holds a result for these
    limits (and no correction is to be applied)."""

    limits: dict[str, float] = field(default_factory=dict)
    settings: dict[str, float] = field(default_factory=dict)  # the camera facts (ProtocolSettings)
    apply: bool = False
    overwrite: bool = False  # measure again even when a result for these limits is stored

    def __call__(self, session: str) -> dict[str, Any]:
        limits = SyncLimits(**self.limits)
        plot = Path(session).with_suffix(".sync.png")
        with SessionReader(session) as reader:
            stored = reader.analysis()
        same_limits = (
            stored.get("sync_limits")
            and json.loads(stored["sync_limits"]) == limits.__dict__
            and stored.get("sync_estimator") == SYNC_ESTIMATOR
        )
        if same_limits and plot.exists() and not (self.apply or self.overwrite):
            return {
                "action": "up to date",
                "verdict": str(stored["sync_verdict"]).upper(),
                "offset_ms": 1e3 * float(stored["sync_offset_s"]),
            }
        # the plot is ours to replace when the limits are the same
        check_outputs([plot], [session], bool(self.overwrite or same_limits))
        report = verify_sync(
            session,
            limits,
            plot_path=plot,
            store=True,
            apply_correction=self.apply,
            settings=ProtocolSettings(**self.settings),
        )
        return {
            "action": "checked",
            "verdict": report.verdict,
            "offset_ms": 1e3 * report.estimate.offset_s,
        }
