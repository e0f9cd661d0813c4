"""End to end on the simulated bench: record, reconstruct, then `vbfe train` / `vbfe evaluate`."""

import json

import numpy as np
import pytest

from vbfe.acquire import SessionReader, record_session
from vbfe.cli.main import main
from vbfe.estimate.dataset import prepare_session
from vbfe.estimate.model_file import load_model
from vbfe.estimate.train_config import TrainConfig
from vbfe.recon import reconstruct_session
from vbfe.rig_config import builtin_rig
from vbfe.truth import calibration_from_rig, true_rig

CONDITIONS = [(200.0, 0.01, 1), (80.0, 0.02, 2)]  # fast pulls: force rises within a second


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    folder = tmp_path_factory.mktemp("recorded")
    paths = []
    for stiffness, speed, seed in CONDITIONS:
        config = builtin_rig(
            {
                "bench": dict(
                    width=320,
                    height=180,
                    fps=8.0,
                    stiffness_n_per_m=stiffness,
                    pull_speed_m_per_s=speed,
                    rest_s=0.1,
                    hold_s=0.3,
                    seed=seed,
                )
            }
        )
        calibration = calibration_from_rig(true_rig(config))
        path = folder / f"pull_k{stiffness:g}.h5"
        record_session(config, path, duration_s=1.5, calibration_yaml=calibration.to_yaml_text())
        reconstruct_session(path, workers=1)
        paths.append(path)
    return paths


def test_recorded_session_frames_are_labelled_with_the_trocar_force(sessions):
    prepared = prepare_session(sessions[0], TrainConfig(n_points=128))
    with SessionReader(sessions[0]) as reader:
        force = np.linalg.norm(reader.force_at_frames(), axis=1)
        times = reader.frame_times_ns()
        conditions = reader.metadata["conditions"]
    usable = np.isfinite(force)
    assert prepared.n_skipped == np.count_nonzero(~usable)
    np.testing.assert_array_equal(prepared.times_ns, times[usable])
    np.testing.assert_allclose(prepared.targets_n[:, 0], force[usable])
    assert prepared.condition == "200 N/m @ 0.01 m/s"
    assert prepared.conditions["stiffness_n_per_m"] == conditions["stiffness_n_per_m"]
    # the pulled tissue moves: peak displacement rises with the force
    assert np.corrcoef(prepared.targets_n[:, 0], prepared.displacement_m)[0, 1] > 0.7
    assert np.all(np.abs(prepared.pools[..., 2] - 0.06) < 0.03)  # tissue ~6 cm from the camera


def test_cli_trains_and_evaluates_on_recorded_sessions(sessions, tmp_path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_text(
        "[train]\nepochs = 3\nbatch_size = 8\nn_points = 64\nthreads = 1\n"
        "conv_channels = [8, 16]\nhead_channels = [8]\nval_fraction = 0.5\n"
    )
    model_path = tmp_path / "model.pt"
    assert (
        main(
            [
                "train",
                *map(str, sessions),
                "--out",
                str(model_path),
                "--config",
                str(rig),
                "--learning-rate",
                "0.01",
            ]
        )
        == 0
    )
    assert "model written to" in capsys.readouterr().out
    model = load_model(model_path)
    assert model.config.n_points == 64 and model.config.learning_rate == 0.01
    split = model.record["split"]
    assert sorted(split["train"] + split["val"]) == sorted(map(str, sessions))
    assert len(split["train"]) == len(split["val"]) == 1

    assert (
        main(["evaluate", str(model_path), *map(str, sessions), "--out", str(tmp_path / "report")])
        == 0
    )
    assert "warning: 2 session(s) were used in training" in capsys.readouterr().out
    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    assert set(metrics["metrics"]["hooke"]["per_condition"]) == {
        "200 N/m @ 0.01 m/s",
        "80 N/m @ 0.02 m/s",
    }
    assert len(list((tmp_path / "report").glob("force_*.png"))) == 2
