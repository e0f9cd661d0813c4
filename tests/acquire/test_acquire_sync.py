"""verify-sync finds a known image/force offset, its uncertainty, drifts and drops."""

from __future__ import annotations

import numpy as np
import pytest

from tests.acquire.test_acquire_devices import write_bar_session
from vbfe.acquire import SessionReader
from vbfe.acquire.session.audit import audit_sequence
from vbfe.acquire.session.clock import fit_clock
from vbfe.acquire.sync.check import SyncLimits, verify_sync
from vbfe.acquire.sync.corners import corner_offset
from vbfe.common.errors import SessionError


def test_recovers_injected_37_ms_offset_with_ci_and_drift(tmp_path):
    path = tmp_path / "s.h5"
    # delays 40 ms + Exp(2 ms) for frames, 3 ms + Exp(1 ms) for forces: clock fits map each
    # stream to its median arrival, so the offset is 37 ms + ln 2 · (2 - 1) ms ≈ 37.7 ms; device
    # clocks drift; 20 s, so the lower envelope of the jitter pins the drift to a few ppm
    write_bar_session(
        path,
        seconds=20.0,
        latency_s=0.040,
        jitter_s=0.002,
        drift_ppm=50.0,
        force_rate_hz=1000.0,
        force_latency_s=0.003,
        force_jitter_s=0.001,
        force_drift_ppm=-20.0,
    )
    png = tmp_path / "sync.png"
    report = verify_sync(path, plot_path=png)
    e = report.estimate
    true_s = 0.037 + np.log(2) * 0.001
    assert e.offset_s == pytest.approx(true_s, abs=0.003)
    assert e.ci95_s[0] <= true_s <= e.ci95_s[1]
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
    # a passive PASS needs the whole 95% interval within the limit (this bar's is about ±3 ms)
    limits = SyncLimits(max_offset_s=0.005)
    first = verify_sync(path, limits, apply_correction=True)
    assert first.passed, first.reasons
    assert first.correction_s == pytest.approx(0.025, abs=0.003)
    again = verify_sync(path, limits)  # the reader now applies the stored correction
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
    # lenient on drops, and on the offset so that its whole 95% interval (±4 ms) is within
    lenient = verify_sync(
        path, limits=SyncLimits(max_offset_s=0.006, max_frame_drop=0.2), store=False
    )
    assert lenient.passed, lenient.reasons


def test_audit_counts_drops_duplicates_and_reordering():
    audit = audit_sequence(np.array([0, 1, 1, 2, 5, 4, 6, 9]))
    assert (audit.expected, audit.dropped, audit.duplicated, audit.reordered) == (10, 3, 1, 1)
    assert audit.gaps == [(2, 5), (4, 6), (6, 9)]
    assert audit.drop_fraction == pytest.approx(0.3)


def _ramp_and_hold(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grasper displacement (m) and force (N) of a pull from 1 s to 4 s, then a held force."""
    tp = np.clip(t_s - 1.0, 0.0, 3.0)
    force = 0.4 * tp + 0.3 * (1 - np.exp(-tp / 1.5))
    creep = np.maximum(t_s - 4.0, 0.0)
    return 0.005 * tp + 0.002 * (1 - np.exp(-creep / 2.0)), force


def test_corner_offset_finds_a_sub_frame_lag_at_the_pull_corners():
    rng = np.random.default_rng(3)
    t_force = np.arange(0.0, 6.0, 0.001)
    _, force = _ramp_and_hold(t_force)
    forces = np.outer(force, [0.6, 0.0, -0.8]) + rng.normal(0.0, 0.03, (len(t_force), 3))
    t_frames = np.arange(0.0, 6.0, 1 / 30)
    u, _ = _ramp_and_hold(t_frames)
    components = np.stack([300 * u, 2e4 * u**2, np.sin(200 * u)], axis=1)  # smooth, nonlinear
    components += rng.normal(0.0, 0.01, components.shape)
    lag_s = 0.0213  # not a multiple of the 33 ms frame period
    e = corner_offset(
        ((t_frames + lag_s) * 1e9).astype(np.int64),
        components,
        (t_force * 1e9).astype(np.int64),
        forces,
    )
    assert e.method == "force corners" and e.corners == 2
    assert e.corner_times_s == pytest.approx([1.0, 4.0], abs=0.02)
    assert e.offset_s == pytest.approx(lag_s, abs=0.005)
    assert e.ci95_s[0] <= lag_s <= e.ci95_s[1] and e.ci95_s[1] - e.ci95_s[0] < 0.03


def test_corner_offset_refuses_a_force_without_corners():
    t = np.arange(0.0, 3.0, 0.001)
    forces = np.random.default_rng(0).normal(0.0, 0.03, (len(t), 3))
    frames = np.arange(0.0, 3.0, 1 / 30)
    with pytest.raises(SessionError, match="nothing to align"):
        corner_offset(
            (frames * 1e9).astype(np.int64),
            np.zeros((len(frames), 3)),
            (t * 1e9).astype(np.int64),
            forces,
        )


@pytest.mark.parametrize("seconds", [3.0, 60.0])
def test_clock_drift_uncertainty_is_honest_and_shrinks_with_duration(seconds):
    rng = np.random.default_rng(int(seconds))
    true_ns = np.arange(0, int(seconds * 1e9), 33_333_333)
    device = 7_000_000_000 + np.rint(true_ns * (1 + 50e-6)).astype(np.int64)
    host = true_ns + 45_000_000 + np.rint(rng.normal(0.0, 1e6, len(true_ns))).astype(np.int64)
    fit = fit_clock(device, host)
    # drift of the device clock vs host: +50 ppm; mapped times are the median arrivals
    assert abs(fit.drift_ppm - 50.0) <= 3 * fit.drift_uncertainty_ppm
    assert np.median(fit.to_host(device) - (true_ns + 45_000_000)) == pytest.approx(0, abs=3e5)
    if seconds < 10:
        assert fit.drift_uncertainty_ppm > 20  # a short record cannot pin the drift down
    else:
        assert fit.drift_ppm == pytest.approx(50.0, abs=10) and fit.drift_uncertainty_ppm < 5
