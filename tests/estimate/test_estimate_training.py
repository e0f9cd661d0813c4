"""Training, the model file and evaluation on synthetic pull-and-hold sessions."""

import csv
import json
import re

import h5py
import numpy as np
import pytest
import torch

from tests.estimate_methods import EVALUATED
from vbfe.cli.main import main
from vbfe.common.errors import EstimateError
from vbfe.estimate.dataset import prepare_session
from vbfe.estimate.evaluation import evaluate
from vbfe.estimate.inference import FramePredictor
from vbfe.estimate.model_file import load_model
from vbfe.estimate.network_training import resolve_device
from vbfe.estimate.synthetic import synthetic_session, synthetic_sessions
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.training import best_epochs, train

SMALL = dict(fps=4, points_per_side=20)


def tiny_config(**kw):
    values = dict(
        epochs=30,
        batch_size=16,
        n_points=64,
        patience=10,
        learning_rate=3e-3,
        conv_channels=[16, 32, 64],
        head_channels=[32],
        dropout=0.1,
        val_fraction=1 / 3,
        seed=0,
        threads=1,
        cnn_epochs=15,
        cnn_channels=[4, 8],
        history_frames=0,
        select_min_val_frames=0,  # select on the validation part, however small
    )
    values.update(kw)
    return TrainConfig(**values)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "model.pt"
    result = train(
        synthetic_sessions(repeats=3, seed=1, prefix="train", **SMALL),
        out,
        tiny_config(history_frames=6),
    )
    return out, result


def test_training_writes_a_model_with_its_record(trained):
    path, result = trained
    assert result.model_path == path and path.is_file()
    assert 1 <= result.best_epoch <= result.epochs_run <= 30
    model = load_model(path)
    assert model.config == tiny_config(history_frames=6)
    split = model.record["split"]
    assert len(split["train"]) == 6 and len(split["val"]) == 3
    assert not set(split["train"]) & set(split["val"])
    assert model.record["vbfe_version"]
    assert set(model.baselines) == {
        "mean",
        "linear_displacement",
        "hooke",
        "mlp_displacement_history",
    }
    candidates = {"pointnet", "ridge_height_map", "cnn_depth_change", "ensemble_cnn_hooke"}
    assert set(model.estimators) == set(model.baselines) | candidates
    # the synthetic clouds carry no colours: the texture candidate is skipped, and says why
    assert any(
        note.startswith("hooke_texture_3d skipped: no training frame has a texture")
        for note in result.notes
    )
    # the shipped model is the candidate with the lowest validation MAE, every score stored
    scores = model.record["validation_mae_n"]
    assert set(scores) == set(model.estimators) and result.val_mae_n == scores
    assert model.selected == result.selected == min(candidates, key=scores.get)
    assert model.split.kind == "session"
    session = synthetic_sessions(repeats=1, **SMALL)[0]
    predictor = FramePredictor(model)
    live = np.array([predictor.predict(cloud) for cloud in session.clouds])
    # frame by frame, as vbfe live runs, the shipped model follows the force
    measured = np.linalg.norm(session.forces_n, axis=1)
    assert live.shape == (len(measured), 1) and live.min() >= 0.0
    assert np.abs(live[:, 0] - measured).mean() < 0.3 * np.abs(measured - measured.mean()).mean()
    with pytest.raises(EstimateError, match="rest cloud"):
        FramePredictor(model).predict(np.full((50, 3), np.nan))


def test_every_network_stops_early_and_the_record_times_every_stage(trained):
    path, result = trained
    record = load_model(path).record
    for name, history in record["histories"].items():
        entries = history["history"] if name != "cnn" else history
        runs = len(entries)
        best = record["histories"]["pointnet"]["best_epoch"] if name == "pointnet" else None
        if name == "pointnet":  # stopped by patience: exactly `patience` epochs after its best
            assert history["stopped_by"] in ("patience", "epochs")
            if history["stopped_by"] == "patience":
                assert runs - best == 10
            assert len(history["epoch_seconds"]) == runs and history["device"] == "cpu"
        what = "cnn_depth_change" if name == "cnn" else name
        assert any(n.startswith(f"{what}: ") and "best epoch" in n for n in result.notes), name
    stages = record["stage_seconds"]
    assert {"preparation", "baselines", "pointnet", "cnn_depth_change"} <= set(stages)
    # the interval folds' refits are timed per method, as the selection folds' are
    assert {
        "interval folds",
        "interval folds: baselines",
        "interval folds: cnn_depth_change",
    } <= set(stages)
    for seconds in stages.values():
        assert seconds["wall_s"] >= 0 and seconds["cpu_s"] >= 0
    assert stages["pointnet"]["cpu_s"] > 0
    assert record["device"] == result.device == "cpu"


def test_fold_refits_stop_where_validation_found_the_best_epoch():
    histories = {
        "pointnet": {"history": [{"val_mae_n": 1.0}] * 7, "best_epoch": 4},
        "temporal": {"history": [{"val_mae_n": 1.0}] * 3, "best_epoch": 0},
        "cnn": [{"val_mae_n": v} for v in (3.0, 2.0, 2.5, 1.5, 1.7)],
    }
    # the temporal model whose start was best is not retrained: it stays its PointNet start
    assert best_epochs(histories) == {"pointnet": 4, "temporal": 0, "cnn": 4}
    # fitted without validation: a refit runs every epoch
    assert best_epochs({"pointnet": {"history": [{"train_loss": 1.0}], "best_epoch": 1}}) == {}


def test_model_learns_force_on_held_out_sessions(trained, tmp_path):
    path, _ = trained
    held_out = synthetic_sessions(repeats=1, seed=99, prefix="test", **SMALL)
    report = evaluate(path, held_out, tmp_path / "eval")
    assert report.seen_in_training == []
    assert report.mae_n("pointnet") < 0.5 * report.mae_n("mean")
    assert report.mae_n("selected") < 0.2 * report.mae_n("mean")


def test_evaluation_writes_metrics_plots_and_baselines(trained, tmp_path):
    path, _ = trained
    held_out = synthetic_sessions(repeats=1, seed=98, prefix="test", **SMALL)
    held_out[0].clouds[3] = np.full((50, 3), np.nan)
    report = evaluate(path, held_out, tmp_path / "eval")
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert set(metrics["metrics"]) == EVALUATED
    # the ensemble, read back from the model file, is the mean of its two members' forces
    with open(tmp_path / "eval" / "predictions.csv", newline="") as f:
        scored = list(csv.DictReader(f))
    force = {
        m: np.array([float(r[f"{m}_n"]) for r in scored])
        for m in ("ensemble_cnn_hooke", "cnn_depth_change", "hooke")
    }
    # (where neither member's magnitude was raised to 0 N)
    both = (force["cnn_depth_change"] > 0) & (force["hooke"] > 0)
    assert both.mean() > 0.5
    assert force["ensemble_cnn_hooke"][both] == pytest.approx(
        (force["cnn_depth_change"][both] + force["hooke"][both]) / 2, rel=1e-4, abs=1e-5
    )
    assert not np.allclose(force["cnn_depth_change"], force["hooke"])
    # a magnitude below 0 N is impossible: no method estimates one, at rest or under load
    for method in metrics["metrics"]:
        estimates = np.concatenate([f[method] for f in report.frames.values()])
        assert estimates.min() >= 0.0, method
    for stats in metrics["metrics"].values():
        low, high = stats["overall"]["mae_ci95_n"]
        assert low < stats["overall"]["mae_n"] < high
    rows = list(csv.DictReader(open(tmp_path / "eval" / "predictions.csv")))
    assert len(rows) == metrics["metrics"]["pointnet"]["overall"]["n_frames"]
    first = [r for r in rows if r["session"] == held_out[0].name]
    assert [int(r["frame"]) for r in first[:4]] == [0, 1, 2, 4]  # frame 3 has no cloud
    mean_force = report.frames[held_out[0].name]["mean"][0, 0]
    assert float(first[0]["mean_n"]) == pytest.approx(mean_force, rel=1e-5)
    assert metrics["split"]["kind"] == "session"
    conditions = metrics["metrics"]["pointnet"]["per_condition"]
    assert set(conditions) == {"40 N/m @ 0.01 m/s", "80 N/m @ 0.005 m/s", "200 N/m @ 0.002 m/s"}
    assert (
        sum(c["n_frames"] for c in conditions.values())
        == metrics["metrics"]["pointnet"]["overall"]["n_frames"]
    )
    assert metrics["skipped"][held_out[0].name]["no_cloud"] == 1
    for stats in conditions.values():
        assert stats["rmse_n"] >= stats["mae_n"] > 0
    assert "1 with too few points" in (tmp_path / "eval" / "report.md").read_text()
    pngs = sorted(p.name for p in (tmp_path / "eval" / "").glob("*.png"))
    assert len(pngs) == 4 and all(
        (tmp_path / "eval" / p).read_bytes()[:4] == b"\x89PNG" for p in pngs
    )
    table = (tmp_path / "eval" / "report.md").read_text()
    for label in (
        "PointNet",
        "Mean predictor",
        "Linear on displacement",
        "Hooke",
        "Ridge",
        "split by session",
    ):
        assert label in table
    assert "<table" in (tmp_path / "eval" / "report.html").read_text()
    assert [f.name for f in report.files[:2]] == ["metrics.json", "predictions.csv"]


def test_evaluating_training_sessions_is_flagged(trained, tmp_path):
    path, _ = trained
    report = evaluate(
        path, synthetic_sessions(repeats=1, seed=1, prefix="train", **SMALL)[:1], tmp_path
    )
    assert report.seen_in_training == ["train-k40-v0.01-r0"]
    assert "not held-out" in (tmp_path / "report.md").read_text()


def test_training_is_repeatable_whatever_the_caller_set_and_restores_torch_threads(tmp_path):
    sessions = synthetic_sessions(repeats=2, seed=4, prefix="rep", fps=2, points_per_side=12)
    config = tiny_config(epochs=3, threads=2, cnn_epochs=3)
    torch.set_num_threads(1)
    torch.manual_seed(123)
    first = train(sessions, tmp_path / "a.pt", config)
    assert torch.get_num_threads() == 1
    torch.set_num_threads(2)
    torch.manual_seed(456)  # the caller's random state does not leak into training
    second = train(sessions, tmp_path / "b.pt", config)
    torch.set_num_threads(1)
    a, b = load_model(first.model_path), load_model(second.model_path)
    prepared = prepare_session(sessions[0], config)
    for method in a.estimators:  # every method predicts the same, to the bit
        np.testing.assert_array_equal(
            a.predict_session(prepared, method), b.predict_session(prepared, method), err_msg=method
        )
    assert first.history == second.history and first.val_mae_n == second.val_mae_n


def test_time_limit_only_guards_and_says_so(tmp_path):
    sessions = synthetic_sessions(repeats=2, seed=5, prefix="tl", fps=4, points_per_side=12)
    config = tiny_config(
        epochs=10_000, patience=10_000, time_limit_s=2.0, batch_size=4, model="pointnet"
    )
    result = train(sessions, tmp_path / "tl.pt", config)
    assert any(
        n.startswith("warning: pointnet was stopped by the time limit") for n in result.notes
    )
    assert result.epochs_run < 10_000
    # the schedule is the configured one, not re-sized to the time: still near the top
    assert result.history[-1]["lr"] > 0.99 * config.learning_rate
    assert result.duration_s < 2.0 + 10.0  # preparation plus at most one batch past the limit


def test_without_validation_data_training_says_so_and_runs_the_fixed_epochs(tmp_path):
    sessions = synthetic_sessions(repeats=1, seed=6, prefix="nv", fps=2, points_per_side=12)
    result = train(
        sessions, tmp_path / "nv.pt", tiny_config(epochs=4, val_fraction=0.0, cnn_epochs=2)
    )
    assert any("too little data for a validation set" in n for n in result.notes)
    assert result.epochs_run == result.best_epoch == 4


def test_auto_device_is_the_gpu_torch_sees_else_the_cpu(monkeypatch):
    assert TrainConfig().device == "auto"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == resolve_device("cpu") == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto") == resolve_device("cuda") == torch.device("cuda")
    assert resolve_device("cpu") == torch.device("cpu")  # asked for: the CPU even with a GPU


def test_cuda_request_without_a_gpu_is_refused(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    sessions = synthetic_sessions(repeats=1, seed=6, prefix="cu", fps=2, points_per_side=12)
    with pytest.raises(EstimateError, match="CUDA"):
        train(sessions, tmp_path / "cu.pt", tiny_config(epochs=1, device="cuda"))


def test_three_axis_target(tmp_path):
    sessions = synthetic_sessions(repeats=2, seed=4, prefix="xyz", fps=2, points_per_side=12)
    result = train(sessions, tmp_path / "xyz.pt", tiny_config(epochs=2, target="xyz", cnn_epochs=2))
    model = load_model(result.model_path)
    prepared = prepare_session(sessions[0], model.config)
    for method in model.estimators:
        assert model.predict_session(prepared, method).shape == (prepared.n_used, 3), method


@pytest.mark.parametrize(
    "change, message",
    [
        ({"format_version": 99}, "format version"),
        ({"format": "something-else"}, "not a vbfe model file"),
    ],
)
def test_model_file_of_another_version_or_architecture_is_refused(
    trained, tmp_path, change, message
):
    path, _ = trained
    payload = torch.load(path, weights_only=True)
    payload.update(change)
    other = tmp_path / "other.pt"
    torch.save(payload, other)
    with pytest.raises(EstimateError, match=message) as info:
        load_model(other)
    assert str(other) in str(info.value)


def test_files_that_are_not_models_are_refused(tmp_path):
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a model at all")
    with h5py.File(tmp_path / "session.h5", "w") as f:
        f["x"] = np.zeros(3)
    torch.save([1, 2, 3], tmp_path / "list.pt")
    for path in (garbage, tmp_path / "session.h5", tmp_path / "list.pt", tmp_path / "none.pt"):
        with pytest.raises(EstimateError, match=path.name):
            load_model(path)


def test_cli_reports_missing_clouds_in_one_line(tmp_path, capsys):
    session = tmp_path / "run1.h5"
    session.write_bytes(b"")
    assert main(["train", str(session), "--out", str(tmp_path / "m.pt")]) == 2
    err = capsys.readouterr().err.strip()
    assert "run1" in err and "vbfe reconstruct" in err and "\n" not in err


def test_cli_evaluate_refuses_a_non_model(tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_text("hello")
    assert main(["evaluate", str(bad), "--out", str(tmp_path / "r")]) == 2
    assert "not a vbfe model file" in capsys.readouterr().err


def test_temporal_model_leaves_its_pointnet_start_only_for_a_validation_gain(tmp_path):
    sessions = synthetic_sessions(repeats=2, seed=3, prefix="warm", fps=2, points_per_side=12)
    labels: list[str] = []
    result = train(
        sessions,
        tmp_path / "warm.pt",
        tiny_config(
            epochs=4,
            temporal_frames=2,
            temporal_span_frames=2,
            temporal_epochs=40,
            patience=5,
            temporal_patience=2,  # its own: it starts trained
            model="temporal",
        ),
        progress=lambda stage, done, total: labels.append(stage),
    )
    # progress per candidate: its stage, its time so far and its best validation loss
    epochs = [label.split(" · ") for label in labels if label.startswith("temporal epochs")]
    assert epochs and all(len(p) == 3 and re.fullmatch(r"\d+ s", p[1]) for p in epochs)
    assert all(re.fullmatch(r"best val loss [\d.e+-]+", p[2]) for p in epochs)
    model = load_model(result.model_path)
    assert model.selected == "temporal" and "forced by --model" in " ".join(result.notes)
    live = FramePredictor(model)  # vbfe live keeps the causal window of the shipped model
    forces = [live.predict(cloud) for cloud in sessions[0].clouds]
    assert all(f.shape == (1,) and np.isfinite(f).all() for f in forces)
    temporal = model.record["histories"]["temporal"]
    assert len(temporal["history"]) >= 1 and temporal["start_val_loss"] > 0
    best = temporal["best_epoch"]
    # a model that stops improving stops `temporal_patience` epochs later, and says so
    assert len(temporal["history"]) == best + 2 and temporal["stopped_by"] == "patience"
    assert f"temporal: stopped after {best + 2} epochs, 2 without a better" in " ".join(
        result.notes
    )
    if best:  # a gain over the start, the PointNet it was built from
        assert temporal["history"][best - 1]["val_loss"] < temporal["start_val_loss"]
    else:  # exactly that PointNet: the same head on the newest cloud, motion correction at zero
        assert any("temporal: no epoch improved on its start" in n for n in result.notes)
        prepared = prepare_session(sessions[0], model.config)
        np.testing.assert_allclose(
            model.predict_session(prepared, "temporal"),
            model.predict_session(prepared, "pointnet"),
            rtol=1e-5,
            atol=1e-6,
        )


@pytest.fixture(scope="module")
def clouds_file(tmp_path_factory):
    """One synthetic session (95 frames) as a clouds file of `vbfe import`, and a tiny rig."""
    from vbfe.estimate.importing import write_clouds

    folder = tmp_path_factory.mktemp("cli")
    s = synthetic_session(
        "press", 80.0, 0.005, np.random.default_rng(7), fps=10, points_per_side=12
    )
    path = write_clouds(
        folder / "press.clouds.h5",
        s.clouds,
        s.times_ns,
        s.forces_n,
        {"label": "press"},
        {"folder": "synthetic"},
    )
    rig = folder / "rig.toml"
    rig.write_text(
        "[train]\nepochs = 2\nbatch_size = 8\nn_points = 32\nthreads = 1\n"
        "conv_channels = [8, 16]\nhead_channels = [8]\ncnn_epochs = 3\n"
        "history_frames = 0\ngap_frames = 3\n"
    )
    return path, rig


def test_cli_time_split_by_stated_frame_ranges(clouds_file, tmp_path, capsys):
    path, rig = clouds_file
    model = tmp_path / "m.pt"
    assert (
        main(
            [
                "train",
                str(path),
                "--out",
                str(model),
                "--config",
                str(rig),
                "--train",
                "0:60",
                "--val",
                "66:80",
                "--test",
                "86:95",
                "--model",
                "ridge",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "press.clouds.h5 train 0:60 val 66:80 test 86:95" in out
    assert "ships ridge_height_map" in out and "forced by --model" in out
    assert load_model(model).split.blocks["test"][str(path)] == [[86, 95]]
    assert main(["evaluate", str(model), str(path), "--out", str(tmp_path / "r")]) == 0
    assert "over 9 frames" in capsys.readouterr().out  # the stated test range only
    assert (
        main(
            [
                "train",
                str(path),
                "--out",
                str(tmp_path / "bad.pt"),
                "--config",
                str(rig),
                "--train",
                "0:60",
                "--val",
                "50:80",
            ]
        )
        == 2
    )
    assert "overlap" in capsys.readouterr().err


def test_cli_blocked_cross_validation_reports_every_fold_and_method(clouds_file, tmp_path, capsys):
    path, rig = clouds_file
    model = tmp_path / "cv.pt"
    assert (
        main(["train", str(path), "--out", str(model), "--config", str(rig), "--folds", "3"]) == 0
    )
    out = capsys.readouterr().out
    folds = [line for line in out.splitlines() if line.startswith("fold ")]
    assert len(folds) == 3 and all("test " in line and "gap 3 frames" in line for line in folds)
    assert "3-fold blocked cross-validation, test MAE mean ± sd (N):" in out
    for method in ("selected", "pointnet", "ridge_height_map", "cnn_depth_change", "mean"):
        assert re.search(rf"{method}: \d+\.\d+ ± \d+\.\d+", out), method
    cv = load_model(model).record["cross_validation"]
    assert len(cv["folds"]) == 3 and cv["summary"]["mean"]["sd_mae_n"] >= 0
    assert "warning: the gap" not in out
    # a gap near the block's length leaves folds little to train on: said, with the way out
    wide = ["--folds", "3", "--gap", "20", "--model", "ridge", "--overwrite"]
    assert main(["train", str(path), "--out", str(model), "--config", str(rig), *wide]) == 0
    out = capsys.readouterr().out
    assert re.search(r"warning: the gap of 20 frames leaves fold 1 \d+ training frames", out)
    assert "lower --gap" in out
    assert main(["train", str(path), "--out", str(tmp_path / "two.pt"), "--folds", "2"]) == 2
    assert "at least 3" in capsys.readouterr().err and not (tmp_path / "two.pt").exists()


def test_a_shipped_model_that_loses_to_a_baseline_is_flagged(tmp_path):
    sessions = synthetic_sessions(repeats=2, seed=8, prefix="lose", fps=2, points_per_side=12)
    result = train(
        sessions, tmp_path / "lose.pt", tiny_config(epochs=1, model="pointnet", learning_rate=1e-5)
    )
    scores = result.val_mae_n
    assert set(scores) == {"mean", "linear_displacement", "hooke", "pointnet"}
    assert scores["pointnet"] > scores["linear_displacement"]  # one epoch barely moves it
    warning = [n for n in result.notes if n.startswith("warning: selected model: pointnet")]
    assert warning and "LOSES to the baseline" in warning[0]
    report = evaluate(
        result.model_path, synthetic_sessions(repeats=1, seed=9, **SMALL), tmp_path / "eval"
    )
    assert report.selected == "pointnet"
    assert "LOSES to the baseline" in (tmp_path / "eval" / "report.md").read_text()
