"""`vbfe import`: depth images / point clouds + a force CSV, trained and evaluated by time split."""

from __future__ import annotations

import csv
import json
import re

import cv2
import numpy as np
import pytest

from tests.cli import vbfe
from tests.estimate_methods import EVALUATED
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
select_min_val_frames = 0  # select on the validation range (here the import is under test)
"""


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
    bump = np.exp(-((u - 34) ** 2 + (v - 22) ** 2) / (2 * 6.0**2))
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
        for t, f in zip(t_s, forces, strict=False):
            writer.writerow([f"{t * 1e3:.3f}", *(f"{x * 1e3:.2f}" for x in f), "21.5"])
    (folder / "rig.toml").write_text(RIG)
    return folder


@pytest.mark.slow
def test_depth_import_trains_and_evaluates_with_a_time_split(depth_dataset, tmp_path):
    data = tmp_path / "tissue.clouds.h5"
    imported = vbfe(
        "import",
        "depth",
        str(depth_dataset / "depth"),
        "--forces",
        str(depth_dataset / "forces.csv"),
        "--out",
        str(data),
        "--force-columns",
        "fx_mN,fy_mN,fz_mN",
        "--force-unit",
        "mN",
        "--time-column",
        "t_ms",
        "--time-unit",
        "ms",
        "--fps",
        str(FPS),
        "--fx",
        str(FX),
        "--fy",
        str(FX),
        "--cx",
        str(CX),
        "--cy",
        str(CY),
        "--depth-scale",
        str(DEPTH_SCALE),
        "--roi",
        "4",
        "2",
        "60",
        "46",
        "--condition",
        "porcine liver",
    )
    assert imported.returncode == 0, imported.stderr
    assert "300 frames, 300 with a force" in imported.stdout
    source = ImportedClouds(data)
    try:
        cloud = source.cloud(0)
        assert 0.7 * 56 * 44 < len(cloud) <= 56 * 44  # the ROI, minus missing depth
        assert cloud[:, 2].min() > 0.079  # frame 0: no force, flat at 80 mm
        np.testing.assert_allclose(cloud[:, 0].min(), (4 - CX) * 0.08 / FX, rtol=0.01)
        np.testing.assert_allclose(cloud[:, 1].max(), (45 - CY) * 0.08 / FX, rtol=0.01)
        np.testing.assert_allclose(
            np.linalg.norm(source.force_at_frames()[45]),
            force_profile(np.array([1.5]))[0],
            atol=0.05,
        )
    finally:
        source.close()

    model, report = tmp_path / "model.pt", tmp_path / "report"
    trained = vbfe(
        "train",
        str(data),
        "--out",
        str(model),
        "--config",
        str(depth_dataset / "rig.toml"),
        "--split",
        "time",
        "--gap",
        "10",
        "--val-fraction",
        "0.2",
        "--test-fraction",
        "0.2",
        "--temporal-frames",
        "3",
        "--target",
        "magnitude",
    )
    assert trained.returncode == 0, trained.stderr
    assert "split by frame ranges [start:stop) in time, gap 10 frames" in trained.stdout
    ranges = re.search(
        r"tissue.clouds.h5 train 0:(\d+) val (\d+):(\d+) test (\d+):300", trained.stdout
    )
    assert ranges, trained.stdout  # train, then validation, then test, 10-frame gaps
    stops = [int(v) for v in ranges.groups()]
    assert stops[1] - stops[0] == 10 and stops[3] - stops[2] == 10
    assert "selected model:" in trained.stdout
    # another spelling of the same file is still recognised as the time-split session
    evaluated = vbfe(
        "evaluate",
        str(model),
        f"{tmp_path}/./{data.name}",
        "--out",
        str(report),
        "--config",
        str(depth_dataset / "rig.toml"),
    )
    assert evaluated.returncode == 0, evaluated.stderr
    text = (report / "report.md").read_text()
    assert "split by frame ranges" in text and "gap 10 frames" in text
    assert "held-out test ranges" in text and "porcine liver" in text
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["split"]["kind"] == "time" and metrics["split"]["gap_frames"] == 10
    assert metrics["seen_in_training"] == []
    methods = metrics["metrics"]
    assert set(methods) == EVALUATED | {"temporal"}
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
        fh.write(
            f"ply\nformat ascii 1.0\nelement vertex {len(clouds[1])}\nproperty double x\n"
            "property double y\nproperty double z\nproperty float confidence\n"
            "end_header\n"
        )
        fh.writelines(f"{x:.17g} {y:.17g} {z:.17g} 1.0\n" for x, y, z in clouds[1])
    np.save(folder / "f2.npy", clouds[2])
    np.save(folder / "f3.npy", clouds[3])
    (tmp_path / "f.csv").write_text("frame,force_lbf\n0,0.5\n1,1.0\n3,2.0\n9,5.0\n")
    out = tmp_path / "c.clouds.h5"
    result = vbfe(
        "import",
        "clouds",
        str(folder),
        "--forces",
        str(tmp_path / "f.csv"),
        "--out",
        str(out),
        "--force-columns",
        "force_lbf",
        "--force-unit",
        "lbf",
        "--frame-column",
        "frame",
        "--fps",
        "10",
        "--force-axis",
        "y",
    )
    assert result.returncode == 0, result.stderr
    assert "4 frames, 3 with a force" in result.stdout
    np.testing.assert_allclose(read_ply(folder / "f1.ply"), clouds[1])
    source = ImportedClouds(out)
    try:
        for i in range(4):
            np.testing.assert_allclose(source.cloud(i), clouds[i], atol=1e-7)
        forces = source.force_at_frames()
        np.testing.assert_allclose(
            forces[[0, 1, 3]],
            [[0, 0.5 * 4.4482216152605, 0], [0, 4.4482216152605, 0], [0, 2 * 4.4482216152605, 0]],
        )
        assert np.isnan(forces[2]).all()
        np.testing.assert_array_equal(source.frame_times_ns(), [0, 1e8, 2e8, 3e8])
    finally:
        source.close()


@pytest.mark.parametrize(
    "change, message",
    [
        ({"--cx": "99"}, "principal point"),
        ({"--roi": ["0", "0", "80", "10"]}, "--roi"),
        ({"--force-columns": "fx_mN,fy_mN,nope"}, "no column"),
        ({"--fx": None}, "--fx"),
    ],
)
def test_bad_import_options_are_one_line_errors(depth_dataset, tmp_path, capsys, change, message):
    options = {
        "--forces": str(depth_dataset / "forces.csv"),
        "--out": str(tmp_path / "x.clouds.h5"),
        "--force-columns": "fx_mN,fy_mN,fz_mN",
        "--time-column": "t_ms",
        "--time-unit": "ms",
        "--fps": "30",
        "--fx": "60",
        "--fy": "60",
        "--cx": "32",
        "--cy": "24",
        "--depth-scale": "0.0001",
    }
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
    assert (
        main(
            [
                "import",
                "depth",
                str(tmp_path / "d"),
                "--forces",
                str(tmp_path / "f.csv"),
                "--out",
                str(tmp_path / "x.clouds.h5"),
                "--force-columns",
                "f",
                "--time-column",
                "t",
                "--fps",
                "1",
                "--fx",
                "5",
                "--fy",
                "5",
                "--cx",
                "4",
                "--cy",
                "4",
                "--depth-scale",
                "0.001",
            ]
        )
        == 2
    )
    assert "16-bit" in capsys.readouterr().err


CROP_FX, CROP_CX, CROP_CY, CROP_ORIGIN = 500.0, 320.0, 240.0, (200, 150)


@pytest.fixture(scope="module")
def unpadded_recording(tmp_path_factory):
    """12 cropped 8×6 depth frames named data1 … data12 (frame i at 500 + 10 i mm, one pixel
    saturated, one missing), forces in a headerless whitespace file of one column."""
    folder = tmp_path_factory.mktemp("unpadded")
    (folder / "depth").mkdir()
    for i in range(1, 13):
        depth = np.full((6, 8), 500 + 10 * i, np.uint16)
        depth[0, 0], depth[1, 1] = 65535, 0
        cv2.imwrite(str(folder / "depth" / f"data{i}.png"), depth)
    (folder / "force.txt").write_text("".join(f"  {0.25 * i:.8f}\n" for i in range(1, 13)))
    return folder


def crop_import_args(folder, out, *extra):
    return [
        "import",
        "depth",
        str(folder / "depth"),
        "--forces",
        str(folder / "force.txt"),
        "--force-columns",
        "0",
        "--fps",
        "30",
        "--fx",
        str(CROP_FX),
        "--fy",
        str(CROP_FX),
        "--cx",
        str(CROP_CX),
        "--cy",
        str(CROP_CY),
        "--depth-scale",
        "0.001",
        "--out",
        str(out),
        *extra,
    ]


def test_a_real_style_recording_imports_as_it_comes(unpadded_recording, tmp_path):
    """Natural order, a crop keeping the camera's principal point, saturated and missing depth
    masked, a depth range, a headerless one-column force file with a scale: one CLI call."""
    out = tmp_path / "r.clouds.h5"
    result = vbfe(
        *crop_import_args(
            unpadded_recording,
            out,
            "--crop-origin",
            *map(str, CROP_ORIGIN),
            "--force-scale",
            "-2",
            "--min-depth",
            "0.515",
            "--max-depth",
            "0.6",
        )
    )
    assert result.returncode == 0, result.stderr
    assert "row i of force.txt is frame i" in result.stdout
    assert "12 frames, 12 with a force" in result.stdout
    source = ImportedClouds(out)
    try:
        for i in range(12):  # file data{i+1}: frame i at 510 + 10 i mm, kept from 520 to 600
            cloud = source.cloud(i)
            assert len(cloud) == (46 if 1 <= i <= 9 else 0)  # 48 pixels less the invalid two
            if len(cloud):
                np.testing.assert_allclose(cloud[:, 2], 0.51 + 0.01 * i, rtol=1e-6)
        z, (v, u) = 0.52, np.mgrid[0:6, 0:8]
        valid = np.ones((6, 8), bool)
        valid[0, 0] = valid[1, 1] = False
        expected = np.column_stack(
            [
                (u[valid] + CROP_ORIGIN[0] - CROP_CX) * z / CROP_FX,
                (v[valid] + CROP_ORIGIN[1] - CROP_CY) * z / CROP_FX,
            ]
        )
        np.testing.assert_allclose(
            np.sort(source.cloud(1)[:, :2], axis=0), np.sort(expected, axis=0), rtol=1e-5
        )
        np.testing.assert_allclose(source.force_at_frames()[:, 2], -0.5 * np.arange(1, 13))
    finally:
        source.close()


def write_random(path, size=400):
    path.write_bytes(np.random.default_rng(7).integers(0, 256, size, np.uint8).tobytes())


def bad_inputs(case, folder, tmp):
    """Arguments of one bad import (``folder``: the unpadded recording, ``tmp``: scratch)."""
    frames = tmp / "frames"
    frames.mkdir()
    forces = tmp / "forces.csv"
    forces.write_text("t,f\n0,1\n0.1,2\n0.2,3\n")
    clouds = [
        "import",
        "clouds",
        str(frames),
        "--forces",
        str(forces),
        "--force-columns",
        "f",
        "--time-column",
        "t",
        "--fps",
        "10",
        "--out",
        str(tmp / "x.clouds.h5"),
    ]
    for i in range(3):
        np.save(frames / f"c{i}.npy", np.full((5, 3), 0.1))
    if case == "unsorted times":
        forces.write_text("t,f\n0,1\n0.2,2\n0.1,3\n")
    elif case == "NaN time":
        forces.write_text("t,f\n0,1\nnan,2\n0.2,3\n")
    elif case == "random-bytes force table":
        write_random(forces)
    elif case == "corrupt npy":
        (frames / "c1.npy").write_bytes((frames / "c1.npy").read_bytes()[:90])
    elif case == "truncated ply":
        write_ply(frames / "c3.ply", np.full((50, 3), 0.1))
        (frames / "c3.ply").write_bytes((frames / "c3.ply").read_bytes()[:-100])
        forces.write_text("t,f\n0,1\n0.1,2\n0.2,3\n0.3,4\n")
    elif case in ("random-bytes png", "mixed sizes"):
        depth = tmp / "depth"
        depth.mkdir()
        for i, shape in enumerate([(6, 8)] * 11 + [(6, 9)]):
            cv2.imwrite(str(depth / f"data{i + 1}.png"), np.full(shape, 500, np.uint16))
        if case == "random-bytes png":
            write_random(depth / "data2.png")
        args = crop_import_args(folder, tmp / "x.clouds.h5", "--crop-origin", "0", "0")
        args[2] = str(depth)
        return args
    elif case == "crop without origin":
        return crop_import_args(folder, tmp / "x.clouds.h5")
    elif case == "headerless named column":
        return [
            a if a != "0" else "force"
            for a in crop_import_args(folder, tmp / "x.clouds.h5", "--crop-origin", "1", "1")
        ]
    elif case == "rows are not frames":
        (tmp / "short.txt").write_text("1\n2\n")
        args = crop_import_args(folder, tmp / "x.clouds.h5", "--crop-origin", "0", "0")
        args[args.index("--forces") + 1] = str(tmp / "short.txt")
        return args
    elif case == "existing output":
        (tmp / "x.clouds.h5").write_bytes(b"keep me")
    return clouds


@pytest.mark.parametrize(
    "case, message",
    [
        ("unsorted times", "force time 3 is earlier than force time 2"),
        ("NaN time", "force time 2 of 3 is not a number"),
        ("random-bytes force table", "not a text table"),
        ("corrupt npy", "c1.npy is not a readable .npy"),
        ("truncated ply", "c3.ply: the file ends before its 50 declared vertices"),
        ("random-bytes png", "data2.png is unreadable"),
        ("mixed sizes", "data12.png is 9x6 but data1.png is 8x6"),
        ("crop without origin", "--crop-origin"),
        ("headerless named column", "no header row"),
        ("rows are not frames", "2 rows for 12 frames"),
        ("existing output", "--overwrite"),
    ],
)
def test_bad_recordings_are_one_line_errors(unpadded_recording, tmp_path, capfd, case, message):
    args = bad_inputs(case, unpadded_recording, tmp_path)
    kept = (tmp_path / "x.clouds.h5").read_bytes() if case == "existing output" else None
    assert main(args) == 2
    err = capfd.readouterr().err.strip()  # file-descriptor level: OpenCV's own warnings too
    assert err.startswith("vbfe import: error:") and message in err and "\n" not in err, err
    if kept is None:
        assert not (tmp_path / "x.clouds.h5").exists()
        assert not list(tmp_path.glob("*.part"))
    else:
        assert (tmp_path / "x.clouds.h5").read_bytes() == kept
