"""verify-sync finds a known image/force offset, its uncertainty, drifts and drops."""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_acquire_devices import write_bar_session
from vbfe.acquire import SessionReader
from vbfe.acquire.audit import audit_sequence
from vbfe.acquire.sync_check import SyncLimits, verify_sync


def test_recovers_injected_37_ms_offset_with_ci_and_drift(tmp_path):
    path = tmp_path / "s.h5"
    # image latency - force latency = 40 ms - 3 ms = 37 ms; device clocks drift; 20 s, so the
    # lower envelope of 2 ms transport jitter pins the drift down to a few ppm
    write_bar_session(path, seconds=20.0, latency_s=0.040, jitter_s=0.002, drift_ppm=50.0,
                      force_rate_hz=1000.0, force_latency_s=0.003, force_jitter_s=0.001,
                      force_drift_ppm=-20.0)
    png = tmp_path / "sync.png"
    report = verify_sync(path, plot_path=png)
    e = report.estimate
    assert e.offset_s == pytest.approx(0.037, abs=0.003)
    assert e.ci95_s[0] <= 0.037 <= e.ci95_s[1]
    assert report.drift_ppm["camera"] == pytest.approx(50.0, abs=10)
    assert report.drift_ppm["force"] == pytest.approx(-20.0, abs=10)
    assert not report.passed and "offset" in report.reasons[0]
    assert png.stat().st_size > 5000
    with SessionReader(path) as s:
        assert s.analysis()["sync_verdict"] == "fail"
        assert s.analysis()["sync_offset_s"] == pytest.approx(e.offset_s)


def test_applied_correction_aligns_the_streams_and_passes(tmp_path):
    path = tmp_path / "s.h5"
    write_bar_session(path, latency_s=0.025, force_rate_hz=500.0)
    first = verify_sync(path, apply_correction=True)
    assert first.passed, first.reasons
    assert first.correction_s == pytest.approx(0.025, abs=0.003)
    again = verify_sync(path)  # the reader now applies the stored correction
    assert abs(again.estimate.offset_s) < 0.003 and again.passed
    assert again.correction_s == pytest.approx(first.correction_s)


def test_negative_offset_when_forces_lag(tmp_path):
    path = tmp_path / "s.h5"
    write_bar_session(path, force_latency_s=0.060, force_rate_hz=500.0, compression="mjpeg")
    report = verify_sync(path, store=False)
    assert report.estimate.offset_s == pytest.approx(-0.060, abs=0.005)


def test_dropped_and_duplicated_frames_are_audited_against_limits(tmp_path):
    path = tmp_path / "s.h5"
    drops = tuple(range(20, 40))  # 20 of ~210 frames lost
    write_bar_session(path, drop_seqs=drops, force_rate_hz=500.0)
    report = verify_sync(path, limits=SyncLimits(max_offset_s=0.003, max_frame_drop=0.05))
    audit = report.audits["camera"]
    assert audit.dropped == 20 and audit.gaps == [(19, 40)]
    assert not report.passed
    assert any("camera dropped" in r for r in report.reasons)
    lenient = verify_sync(path, limits=SyncLimits(max_frame_drop=0.2), store=False)
    assert lenient.passed, lenient.reasons


def test_audit_counts_drops_duplicates_and_reordering():
    audit = audit_sequence(np.array([0, 1, 1, 2, 5, 4, 6, 9]))
    assert (audit.expected, audit.dropped, audit.duplicated, audit.reordered) == (10, 3, 1, 1)
    assert audit.gaps == [(2, 5), (4, 6), (6, 9)]
    assert audit.drop_fraction == pytest.approx(0.3)
