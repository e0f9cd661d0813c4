"""`vbfe demo --quick`: the whole pipeline on the simulated bench, scored against its truth."""

import json
import re
from pathlib import Path

import pytest

from tests.device_skips import device_skips_only
from tests.estimate_methods import EVALUATED
from vbfe.cli.main import main

# the whole pipeline: about five minutes quiet, over ten beside busy processes (the 600 s hang
# guard of pyproject cut it off there)
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--quick", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def numbers(demo_out) -> dict:
    return json.loads((demo_out / "results.json").read_text())


def test_calibration_matches_the_bench_truth(numbers):
    cal = numbers["calibration"]
    for name in ("f", "cx", "cy"):
        assert cal[f"{name}_error"] < 0.005, name
    assert cal["B_error"] < 0.01
    assert cal["rms_px"] < 0.5
    assert cal["projector_f_error"] < 0.05  # quick: six projector poses at 480x270
    assert abs(cal["f_estimated"] - cal["f_true"]) / cal["f_true"] == pytest.approx(cal["f_error"])


def test_reconstruction_depth_error_is_within_one_percent_of_working_distance(numbers):
    recon = numbers["reconstruction"]
    assert recon["verified"]["median_abs_depth_error_m"] <= 0.01 * 0.06
    assert recon["verified"]["valid_fraction"] > 0.5
    assert recon["verified"]["bad_pixel_rate"] <= recon["unverified"]["bad_pixel_rate"]
    for quality in recon["quality"]:  # per-session quality read back from the cloud files
        assert quality["decoded_fraction"] > 0.5 and quality["density"] > 0.5
        assert quality["kept"] + quality["corrected"] + quality["rejected"] == pytest.approx(1)


def test_sync_offset_is_measured_against_the_true_offset(numbers):
    rows = numbers["sync"]["sessions"]
    assert len(rows) == 6 + 3  # the paper's sessions and the freehand trials, all checked
    by_protocol = numbers["sync"]["by_protocol"]
    assert by_protocol["pull-hold"]["sessions"] == 6 and by_protocol["freehand"]["sessions"] == 3
    # freehand trials: one viscoelastic model of the whole trial (measured -0.80, -1.15 and
    # -0.99 ms on these three, 95% half-widths 1.7-2.9 ms)
    assert by_protocol["freehand"]["max_abs_error_s"] <= 0.002
    assert by_protocol["freehand"]["max_half_width_s"] <= 0.003
    for row in rows:
        assert row["true_offset_s"] == pytest.approx(0.037, abs=0.005)
        low, high = row["ci95_s"]
        assert low <= row["true_offset_s"] <= high, row["session"]
        assert abs(row["offset_s"] - row["true_offset_s"]) < 0.010, row["session"]


def test_sync_protocol_session_measures_the_offset_and_passes_once_corrected(numbers):
    p = numbers["sync_protocol"]
    assert p["true_offset_s"] == pytest.approx(0.037)
    assert abs(p["error_s"]) <= 0.001 and p["ci95_s"][0] <= p["true_offset_s"] <= p["ci95_s"][1]
    assert p["flash_latency_s"] == pytest.approx(p["true_flash_latency_s"], abs=0.001)
    # of the 10 taps, a frame the simulated camera never delivered (a starved machine: it
    # renders in real time) can leave a tap unfit: 7 used beside two busy processes (CI)
    assert p["taps_used"] >= (8 if p["camera_device_dropped"] == 0 else 6), p
    assert p["verdict_before"] == "FAIL"
    # after the correction: PASS, or FAIL only for frames a starved simulator never rendered
    # (the full demo at load 4-5: 7.2 % skipped), which the report then names
    assert p["verdict_after_apply"] == "PASS" or device_skips_only(p["reasons_after_apply"]), p


def test_force_model_is_evaluated_beside_the_baselines_on_held_out_sessions(numbers):
    force = numbers["force"]
    assert not set(force["train_sessions"]) & set(force["test_sessions"])
    metrics = force["metrics"]
    assert set(metrics) == EVALUATED | {"temporal", "hooke_texture_3d"}
    assert len(metrics["pointnet"]["per_condition"]) == 3
    mae = {method: metrics[method]["overall"]["mae_n"] for method in metrics}
    # The clouds carry the force: peak displacement alone (deterministic, fitted on the
    # training sessions) clearly beats the mean predictor on sessions it never saw.
    assert mae["linear_displacement"] < 0.8 * mae["mean"]
    # Recordings are reproducible and training is seeded on one thread; across seeds of the
    # quick run (one training session per condition) PointNet reading each point's depth
    # change against the rest frame measured 0.45-0.52x the mean predictor and the temporal
    # model 0.41-0.52x; the better of the two 0.75-0.91x the better displacement baseline.
    assert mae["pointnet"] <= 0.8 * mae["mean"]
    assert mae["temporal"] <= 0.8 * mae["mean"]
    best_baseline = min(mae["linear_displacement"], mae["hooke"])
    assert min(mae["pointnet"], mae["temporal"]) <= 1.05 * best_baseline
    # the shipped model, selected on whole held-out sessions, beats the mean predictor on the
    # held-out sessions (quick run selecting on one paper session and one freehand trial that
    # no network stopped on: the mean of CNN and Hooke shipped, 0.54 N against 0.87 N, freehand
    # 0.14 against 0.47 N; it validated on later frames of its training trials before and
    # shipped the ridge, 1.50 N against 0.90 N)
    freehand = {m: v["overall"]["mae_n"] for m, v in force["freehand"]["metrics"].items()}
    shipped = force["shipped"], force["freehand"]["shipped"]
    assert mae[shipped[0]] < mae["mean"] and freehand[shipped[1]] < freehand["mean"]
    assert set(force["per_phase"]) == set(force["metrics"])  # estimators only, no flag
    phases = force["per_phase"]["pointnet"]
    assert set(phases) == {"pull", "hold"} and phases["hold"]["n_frames"] > 0


def test_held_out_freehand_trials_are_reported_apart(numbers, demo_out):
    force, freehand = numbers["force"], numbers["force"]["freehand"]
    trained = [s for s in force["train_sessions"] if s.startswith("freehand")]
    assert len(trained) == 2 and len(freehand["test_sessions"]) == 1
    assert not set(freehand["test_sessions"]) & set(force["train_sessions"])
    metrics = freehand["metrics"]
    assert set(metrics) == set(force["metrics"])  # every method evaluated, on both sets
    mae = {method: metrics[method]["overall"]["mae_n"] for method in metrics}
    best = freehand["best"]
    assert best["mae_n"] == min(v for m, v in mae.items() if m != "mean")
    assert best["ratio_to_mean"] == pytest.approx(best["mae_n"] / mae["mean"])
    # quick run (one 6 s held-out trial): Hooke's law 0.16 N, 0.34x the mean predictor
    # (0.48 N); the MLP on the displacement history, best on the paper's protocol by its
    # timing, 0.47 N here. With textured freehand trials: Hooke 0.17 N (0.44x the mean's
    # 0.38 N), Hooke on the texture's 3D displacement 0.29 N (fitted on two 6 s trials whose
    # texture-to-truth gain is 1.00 and 1.12, held-out 1.15). (Three trained and two held-out 8 s
    # trials: the temporal model 0.30 N, 0.42x the mean predictor's 0.72 N; the MLP 0.58 N.)
    assert best["ratio_to_mean"] <= 0.5
    assert mae["mlp_displacement_history"] > 1.5 * best["mae_n"]
    assert {"pull", "hold"} <= set(freehand["per_phase"]["mean"])
    html = (demo_out / "index.html").read_text()
    assert "Force estimation on held-out freehand trials" in html
    assert "freehand held-out MAE, best method" in html


def test_report_links_every_plot_and_shows_the_verdicts(demo_out):
    html = (demo_out / "index.html").read_text()
    images = re.findall(r'<img src="([^"]+)"', html)
    assert len(images) >= 5
    for src in images:
        assert (demo_out / src).is_file(), src
    assert html.count("PASS") + html.count("FAIL") >= 10
    assert "pattern decoded" in html
    for heading in (
        "calibration",
        "Synchronisation",
        "Sync protocol session",
        "reconstruction",
        "Force estimation",
    ):
        assert heading in html
