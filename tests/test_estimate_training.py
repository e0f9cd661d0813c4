"""Training, the model file and evaluation on synthetic pull-and-hold sessions."""

import json

import h5py
import numpy as np
import pytest
import torch

from vbfe.cli.main import main
from vbfe.estimate.errors import EstimateError
from vbfe.estimate.evaluation import evaluate
from vbfe.estimate.model_file import load_model
from vbfe.estimate.dataset import prepare_session
from vbfe.estimate.synthetic import synthetic_sessions
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.training import train

SMALL = dict(fps=4, points_per_side=20)


def tiny_config(**kw):
    values = dict(epochs=30, batch_size=16, n_points=64, patience=10, learning_rate=3e-3,
                  conv_channels=[16, 32, 64], head_channels=[32], dropout=0.1,
                  val_fraction=1 / 3, seed=0, threads=1)
    values.update(kw)
    return TrainConfig(**values)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "model.pt"
    result = train(synthetic_sessions(repeats=3, seed=1, prefix="train", **SMALL), out,
                   tiny_config())
    return out, result


def test_training_writes_a_model_with_its_record(trained):
    path, result = trained
    assert result.model_path == path and path.is_file()
    assert 1 <= result.best_epoch <= result.epochs_run <= 30
    model = load_model(path)
    assert model.config == tiny_config()
    split = model.record["split"]
    assert len(split["train"]) == 6 and len(split["val"]) == 3
    assert not set(split["train"]) & set(split["val"])
    assert model.record["normalization"]["target_std_n"][0] > 0.5
    assert model.record["vbfe_version"]
    assert set(model.baselines) == {"mean", "linear_displacement", "hooke", "ridge_height_map",
                                   "mlp_displacement_history"}
    assert model.split.kind == "session" and model.temporal is None
    clouds = synthetic_sessions(repeats=1, **SMALL)[0].clouds
    prediction = model.predict_cloud(clouds[-1], rest_points=clouds[0])
    assert prediction.shape == (1,) and np.isfinite(prediction).all()
    with pytest.raises(EstimateError, match="rest cloud"):
        model.predict_cloud(clouds[-1])


def test_model_learns_force_on_held_out_sessions(trained, tmp_path):
    path, _ = trained
    held_out = synthetic_sessions(repeats=1, seed=99, prefix="test", **SMALL)
    report = evaluate(path, held_out, tmp_path / "eval")
    assert report.seen_in_training == []
    assert report.mae_n("pointnet") < 0.5 * report.mae_n("mean")


def test_evaluation_writes_metrics_plots_and_baselines(trained, tmp_path):
    path, _ = trained
    held_out = synthetic_sessions(repeats=1, seed=98, prefix="test", **SMALL)
    held_out[0].clouds[3] = np.full((50, 3), np.nan)
    report = evaluate(path, held_out, tmp_path / "eval")
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert set(metrics["metrics"]) == {"pointnet", "mean", "linear_displacement", "hooke",
                                       "ridge_height_map", "mlp_displacement_history"}
    assert metrics["split"]["kind"] == "session"
    conditions = metrics["metrics"]["pointnet"]["per_condition"]
    assert set(conditions) == {"40 N/m @ 0.01 m/s", "80 N/m @ 0.005 m/s",
                               "200 N/m @ 0.002 m/s"}
    assert sum(c["n_frames"] for c in conditions.values()) == \
        metrics["metrics"]["pointnet"]["overall"]["n_frames"]
    assert metrics["skipped"][held_out[0].name]["skipped"] == 1
    for stats in conditions.values():
        assert stats["rmse_n"] >= stats["mae_n"] > 0
    pngs = sorted(p.name for p in (tmp_path / "eval").glob("*.png"))
    assert len(pngs) == 4 and all((tmp_path / "eval" / p).read_bytes()[:4] == b"\x89PNG"
                                  for p in pngs)
    table = (tmp_path / "eval" / "report.md").read_text()
    for label in ("PointNet", "Mean predictor", "Linear on displacement", "Hooke", "Ridge",
                  "split by session"):
        assert label in table
    assert "<table" in (tmp_path / "eval" / "report.html").read_text()
    assert report.files[0].name == "metrics.json"


def test_evaluating_training_sessions_is_flagged(trained, tmp_path):
    path, _ = trained
    report = evaluate(path, synthetic_sessions(repeats=1, seed=1, prefix="train", **SMALL)[:1],
                      tmp_path)
    assert report.seen_in_training == ["train-k40-v0.01-r0"]
    assert "not held-out" in (tmp_path / "report.md").read_text()


def test_cpu_training_is_repeatable_and_leaves_torch_threads_alone(tmp_path):
    sessions = synthetic_sessions(repeats=2, seed=4, prefix="rep", fps=2, points_per_side=12)
    torch.set_num_threads(1)
    first = train(sessions, tmp_path / "a.pt", tiny_config(epochs=3, threads=2))
    assert torch.get_num_threads() == 1
    second = train(sessions, tmp_path / "b.pt", tiny_config(epochs=3, threads=2))
    a, b = load_model(first.model_path), load_model(second.model_path)
    for name, tensor in a.network.state_dict().items():
        assert torch.equal(tensor, b.network.state_dict()[name]), name
    assert first.history == second.history


def test_time_limit_stops_within_an_epoch_and_anneals_the_learning_rate(tmp_path):
    sessions = synthetic_sessions(repeats=2, seed=5, prefix="tl", fps=4, points_per_side=12)
    config = tiny_config(epochs=10_000, patience=10_000, time_limit_s=3.0, batch_size=4)
    result = train(sessions, tmp_path / "tl.pt", config)
    assert any("time limit" in note for note in result.notes)
    assert result.epochs_run < 10_000
    lrs = [entry["lr"] for entry in result.history]
    assert lrs[-1] < 0.5 * config.learning_rate  # the schedule was sized to the limit
    assert result.duration_s < 3.0 + 10.0  # preparation plus at most one batch past the limit


def test_without_validation_data_training_says_so_and_runs_the_fixed_epochs(tmp_path):
    sessions = synthetic_sessions(repeats=1, seed=6, prefix="nv", fps=2, points_per_side=12)
    result = train(sessions, tmp_path / "nv.pt", tiny_config(epochs=4, val_fraction=0.0))
    assert any("too little data for a validation set" in n for n in result.notes)
    assert result.epochs_run == result.best_epoch == 4
    assert load_model(result.model_path).record["early_stopping_on"].startswith("none")


def test_cuda_request_without_a_gpu_is_refused(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    sessions = synthetic_sessions(repeats=1, seed=6, prefix="cu", fps=2, points_per_side=12)
    with pytest.raises(EstimateError, match="CUDA"):
        train(sessions, tmp_path / "cu.pt", tiny_config(epochs=1, device="cuda"))


def test_three_axis_target(tmp_path):
    sessions = synthetic_sessions(repeats=2, seed=4, prefix="xyz", fps=2, points_per_side=12)
    result = train(sessions, tmp_path / "xyz.pt", tiny_config(epochs=2, target="xyz"))
    model = load_model(result.model_path)
    clouds = sessions[0].clouds
    assert model.predict_cloud(clouds[-1], rest_points=clouds[0]).shape == (3,)


@pytest.mark.parametrize("change, message", [
    ({"format_version": 99}, "format version"),
    ({"architecture": "dgcnn"}, "architecture"),
    ({"architecture_version": 0}, "architecture version"),
    ({"format": "something-else"}, "not a vbfe model file"),
])
def test_model_file_of_another_version_or_architecture_is_refused(trained, tmp_path, change,
                                                                   message):
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
    result = train(sessions, tmp_path / "warm.pt",
                   tiny_config(epochs=4, temporal_frames=2, temporal_span_frames=2,
                               temporal_epochs=4))
    model = load_model(result.model_path)
    temporal = model.record["temporal"]
    assert len(temporal["history"]) >= 1 and temporal["start_val_loss"] > 0
    best = temporal["best_epoch"]
    if best:  # a gain over the start, the PointNet it was built from
        assert temporal["history"][best - 1]["val_loss"] < temporal["start_val_loss"]
    else:  # exactly that PointNet: the same head on the newest cloud, motion correction at zero
        prepared = prepare_session(sessions[0], model.config)
        np.testing.assert_allclose(model.predict_session_temporal(prepared),
                                   model.predict_session(prepared), rtol=1e-5, atol=1e-6)
