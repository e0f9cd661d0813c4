"""`vbfe import`: depth images / point clouds + a force CSV → train and evaluate with a time split."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys

import cv2
import numpy as np
import pytest

from vbfe.cli.main import main
from vbfe.estimate.importing import read_ply
from vbfe.estimate.sources import ImportedClouds
from vbfe.recon import write_ply

FX, CX, CY, WIDTH, HEIGHT, FPS = 60.0, 32.0, 24.0, 64, 48, 30.0
DEPTH_SCALE = 1e-4  # 0.1 mm per unit
RIG = """
[train]
conv_channels = [16, 32, 64]
head_channels = [32]
batch_size = 16
learning_rate = 0.003
epochs = 12
patience = 12
n_points = 96
threads = 1
temporal_span_frames = 6
"""


def vbfe(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vbfe.cli.main", *args], capture_output=True,
                          text=True, timeout=600)


def force_profile(t_s: np.ndarray) -> np.ndarray:
    """Pulls of different heights, each held and released (newtons, |F|)."""
    cycle, phase = np.divmod(t_s, 2.0)
    height = 0.5 + (cycle * 0.37) % 1.5
    return height * np.clip(np.minimum(phase / 0.6, (2.0 - phase) / 0.4), 0, 1)


@pytest.fixture(scope="module")
def depth_dataset(tmp_path_factory):
    """300 depth frames of a patch pulled towards the camera, forces at 200 Hz in mN / ms."""
    folder = tmp_path_factory.mktemp("rgbd")
    frames = folder / "depth"
    frames.mkdir()
    rng = np.random.default_rng(0)
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
    bump = np.exp(-((u - 34) ** 2 + (v - 22) ** 2) / (2 * 6.0 ** 2))
    for i in range(300):
        force = force_profile(np.array([i / FPS]))[0]
        z_m = 0.08 - 0.004 * force * bump + rng.normal(0, 2e-5, bump.shape)
        depth = np.round(z_m / DEPTH_SCALE).astype(np.uint16)
        depth[rng.random(depth.shape) < 0.03] = 0  # missing depth
        cv2.imwrite(str(frames / f"depth_{i:04d}.png"), depth)
    t_s = np.arange(0, 300 / FPS, 1 / 200)
    direction = np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
    forces = force_profile(t_s)[:, None] * direction + rng.normal(0, 0.01, (len(t_s), 3))
    with open(folder / "forces.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["t_ms", "fx_mN", "fy_mN", "fz_mN", "temperature"])
        for t, f in zip(t_s, forces):
            writer.writerow([f"{t * 1e3:.3f}", *(f"{x * 1e3:.2f}" for x in f), "21.5"])
    (folder / "rig.toml").write_text(RIG)
    return folder


def test_depth_import_trains_and_evaluates_with_a_time_split(depth_dataset, tmp_path):
    data = tmp_path / "tissue.clouds.h5"
    imported = vbfe("import", "depth", str(depth_dataset / "depth"), "--forces",
                    str(depth_dataset / "forces.csv"), "--out", str(data), "--force-columns",
                    "fx_mN,fy_mN,fz_mN", "--force-unit", "mN", "--time-column", "t_ms",
                    "--time-unit", "ms", "--fps", str(FPS), "--fx", str(FX), "--fy", str(FX),
                    "--cx", str(CX), "--cy", str(CY), "--depth-scale", str(DEPTH_SCALE),
                    "--roi", "4", "2", "60", "46", "--condition", "porcine liver")
    assert imported.returncode == 0, imported.stderr
    assert "300 frames, 300 with a force" in imported.stdout
    source = ImportedClouds(data)
    try:
        cloud = source.cloud(0)
        assert 0.7 * 56 * 44 < len(cloud) <= 56 * 44  # the ROI, minus missing depth
        assert cloud[:, 2].min() > 0.079  # frame 0: no force, flat at 80 mm
        np.testing.assert_allclose(cloud[:, 0].min(), (4 - CX) * 0.08 / FX, rtol=0.01)
        np.testing.assert_allclose(cloud[:, 1].max(), (45 - CY) * 0.08 / FX, rtol=0.01)
        np.testing.assert_allclose(np.linalg.norm(source.force_at_frames()[45]),
                                   force_profile(np.array([1.5]))[0], atol=0.05)
    finally:
        source.close()

    model, report = tmp_path / "model.pt", tmp_path / "report"
    trained = vbfe("train", str(data), "--out", str(model), "--config",
                   str(depth_dataset / "rig.toml"), "--split", "time", "--gap", "10",
                   "--val-fraction", "0.2", "--test-fraction", "0.2", "--temporal-frames", "3",
                   "--target", "magnitude")
    assert trained.returncode == 0, trained.stderr
    assert "split by frame ranges [start:stop) in time, gap 10 frames" in trained.stdout
    ranges = re.search(r"tissue.clouds.h5 train 0:(\d+) val (\d+):(\d+) test (\d+):300",
                       trained.stdout)
    assert ranges, trained.stdout  # train, then validation, then test, 10-frame gaps
    stops = [int(v) for v in ranges.groups()]
    assert stops[1] - stops[0] == 10 and stops[3] - stops[2] == 10
    assert "selected model:" in trained.stdout
    # another spelling of the same file is still recognised as the time-split session
    evaluated = vbfe("evaluate", str(model), f"{tmp_path}/./{data.name}", "--out", str(report),
                     "--config",
                     str(depth_dataset / "rig.toml"))
    assert evaluated.returncode == 0, evaluated.stderr
    text = (report / "report.md").read_text()
    assert "split by frame ranges" in text and "gap 10 frames" in text
    assert "held-out test ranges" in text and "porcine liver" in text
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["split"]["kind"] == "time" and metrics["split"]["gap_frames"] == 10
    assert metrics["seen_in_training"] == []
    methods = metrics["metrics"]
    assert set(methods) == {"pointnet", "temporal", "mean", "linear_displacement", "hooke",
                            "ridge_height_map", "mlp_displacement_history", "cnn_depth_change"}
    # the last fifth, less nothing (the test range keeps its frames; gaps come out of the
    # lower parts), out of 300 frames
    assert methods["mean"]["overall"]["n_frames"] == 60
    mae = {m: methods[m]["overall"]["mae_n"] for m in methods}
    assert mae["ridge_height_map"] < 0.3 * mae["mean"]  # the depth maps carry the force
    assert min(mae["pointnet"], mae["temporal"]) < 0.8 * mae["mean"]


def test_point_cloud_folder_with_frame_indexed_forces(tmp_path):
    folder = tmp_path / "clouds"
    folder.mkdir()
    rng = np.random.default_rng(1)
    clouds = [rng.normal(0, 0.01, (50 + i, 3)) + [0, 0, 0.08] for i in range(4)]
    write_ply(folder / "f0.ply", clouds[0])
    with open(folder / "f1.ply", "w") as fh:  # ASCII PLY with an extra property
        fh.write(f"ply\nformat ascii 1.0\nelement vertex {len(clouds[1])}\nproperty double x\n"
                 "property double y\nproperty double z\nproperty float confidence\n"
                 "end_header\n")
        fh.writelines(f"{x:.17g} {y:.17g} {z:.17g} 1.0\n" for x, y, z in clouds[1])
    np.save(folder / "f2.npy", clouds[2])
    np.save(folder / "f3.npy", clouds[3])
    (tmp_path / "f.csv").write_text("frame,force_lbf\n0,0.5\n1,1.0\n3,2.0\n9,5.0\n")
    out = tmp_path / "c.clouds.h5"
    result = vbfe("import", "clouds", str(folder), "--forces", str(tmp_path / "f.csv"), "--out",
                  str(out), "--force-columns", "force_lbf", "--force-unit", "lbf",
                  "--frame-column", "frame", "--fps", "10", "--force-axis", "y")
    assert result.returncode == 0, result.stderr
    assert "4 frames, 3 with a force" in result.stdout
    np.testing.assert_allclose(read_ply(folder / "f1.ply"), clouds[1])
    source = ImportedClouds(out)
    try:
        for i in range(4):
            np.testing.assert_allclose(source.cloud(i), clouds[i], atol=1e-7)
        forces = source.force_at_frames()
        np.testing.assert_allclose(forces[[0, 1, 3]], [[0, 0.5 * 4.4482216152605, 0],
                                                       [0, 4.4482216152605, 0],
                                                       [0, 2 * 4.4482216152605, 0]])
        assert np.isnan(forces[2]).all()
        np.testing.assert_array_equal(source.frame_times_ns(), [0, 1e8, 2e8, 3e8])
    finally:
        source.close()


@pytest.mark.parametrize("change, message", [
    ({"--cx": "99"}, "principal point"),
    ({"--roi": ["0", "0", "80", "10"]}, "--roi"),
    ({"--force-columns": "fx_mN,fy_mN,nope"}, "no column"),
    ({"--fx": None}, "--fx"),
])
def test_bad_import_options_are_one_line_errors(depth_dataset, tmp_path, capsys, change,
                                                message):
    options = {"--forces": str(depth_dataset / "forces.csv"),
               "--out": str(tmp_path / "x.clouds.h5"), "--force-columns": "fx_mN,fy_mN,fz_mN",
               "--time-column": "t_ms", "--time-unit": "ms", "--fps": "30", "--fx": "60",
               "--fy": "60", "--cx": "32", "--cy": "24", "--depth-scale": "0.0001"}
    options.update(change)
    args = ["import", "depth", str(depth_dataset / "depth")]
    for flag, value in options.items():
        if value is not None:
            args += [flag, *([value] if isinstance(value, str) else value)]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vbfe import: error:") and message in err and "\n" not in err
    assert not (tmp_path / "x.clouds.h5").exists()


def test_an_eight_bit_png_is_refused(tmp_path, capsys):
    (tmp_path / "d").mkdir()
    cv2.imwrite(str(tmp_path / "d" / "a.png"), np.zeros((8, 8), np.uint8))
    (tmp_path / "f.csv").write_text("t,f\n0,1\n1,2\n")
    assert main(["import", "depth", str(tmp_path / "d"), "--forces", str(tmp_path / "f.csv"),
                 "--out", str(tmp_path / "x.clouds.h5"), "--force-columns", "f",
                 "--time-column", "t", "--fps", "1", "--fx", "5", "--fy", "5", "--cx", "4",
                 "--cy", "4", "--depth-scale", "0.001"]) == 2
    assert "16-bit" in capsys.readouterr().err
