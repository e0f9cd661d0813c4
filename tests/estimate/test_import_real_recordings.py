"""`vbfe import` on public real recordings (not vendored: no licence; see tests/data/README.md).

Set ``VBFE_REALDATA`` to a folder holding ``learning-to-see-forces/data`` (the ``data/``
folder of github.com/gaocong13/Learning-to-See-Forces) and/or ``punyo/`` (``pc/pc_*.npy`` from
``demo/0/expand`` of github.com/uiuc-iml/punyo_force_estimation and ``forces.csv``, its
``data.json`` rows ``[t_s, pressure_hPa, joints[6], wrench[6]]`` as
``frame,t_s,pressure_hpa,fx,fy,fz,tx,ty,tz`` from the wrench; docs/how-to/import.md); each test
skips without its data. Nothing is fetched at test time.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.cli import vbfe
from vbfe.estimate.model_file import load_model
from vbfe.estimate.sources import ImportedClouds

REALDATA = Path(os.environ.get("VBFE_REALDATA", "/nonexistent"))
ROOT = REALDATA / "learning-to-see-forces" / "data"
PUNYO = REALDATA / "punyo"
KINECT_V1_DEPTH = {"fx": 582.6245, "fy": 582.6910, "cx": 313.0448, "cy": 238.4439}  # the authors'

pytestmark = pytest.mark.slow


@pytest.mark.skipif(
    not (ROOT / "depthimage1-1" / "data1000.png").exists(),
    reason="set VBFE_REALDATA to a folder with learning-to-see-forces/data",
)
def test_learning_to_see_forces_imports_in_frame_order(tmp_path):
    out = tmp_path / "ltsf.clouds.h5"
    result = vbfe(
        "import",
        "depth",
        str(ROOT / "depthimage1-1"),
        "--forces",
        str(ROOT / "Force_ori" / "data1-1-z.txt"),
        "--force-columns",
        "0",
        "--fps",
        "30",
        *(a for k, v in KINECT_V1_DEPTH.items() for a in (f"--{k}", str(v))),
        "--depth-scale",
        "0.001",
        "--crop-origin",
        "0",
        "0",
        "--pixel-step",
        "5",
        "--out",
        str(out),
    )
    assert result.returncode == 0, result.stderr
    assert "1000 frames, 1000 with a force" in result.stdout
    forces = np.loadtxt(ROOT / "Force_ori" / "data1-1-z.txt")
    source = ImportedClouds(out)
    try:
        np.testing.assert_allclose(source.force_at_frames()[:, 2], forces)
        for i in (9, 99, 999):  # data10, data100, data1000: frames 9, 99, 999 (not text order)
            depth = cv2.imread(
                str(ROOT / "depthimage1-1" / f"data{i + 1}.png"), cv2.IMREAD_UNCHANGED
            )[::5, ::5]
            z = np.sort(depth[(depth > 0) & (depth < 65535)].ravel() * 1e-3)
            np.testing.assert_allclose(np.sort(source.cloud(i)[:, 2]), z, rtol=1e-6)
    finally:
        source.close()


NEEDS_PUNYO = pytest.mark.skipif(
    not (PUNYO / "pc" / "pc_149.npy").exists(),
    reason="set VBFE_REALDATA to a folder with punyo/pc and punyo/forces.csv",
)


def _import_punyo(out: Path) -> None:
    result = vbfe(
        "import",
        "clouds",
        str(PUNYO / "pc"),
        "--forces",
        str(PUNYO / "forces.csv"),
        "--force-columns",
        "fx,fy,fz",
        "--frame-column",
        "frame",
        "--frame-times",
        str(PUNYO / "forces.csv"),
        "--frame-time-column",
        "t_s",
        "--min-depth",
        "0.01",
        "--max-depth",
        "0.2",
        "--out",
        str(out),
    )
    assert result.returncode == 0, result.stderr
    assert "150 frames, 150 with a force" in result.stdout


@NEEDS_PUNYO
def test_punyo_organised_clouds_keep_the_bubble_only(tmp_path):
    out = tmp_path / "punyo.clouds.h5"
    _import_punyo(out)
    source = ImportedClouds(out)
    try:
        raw = np.load(PUNYO / "pc" / "pc_10.npy")  # frame 10, not pc_100 (text order)
        z = raw[:, 2]
        kept = np.sort(z[(z >= 0.01) & (z <= 0.2)])
        np.testing.assert_allclose(np.sort(source.cloud(10)[:, 2]), kept, rtol=1e-6)
        assert np.all(np.diff(source.frame_times_ns()) > 0)
    finally:
        source.close()


@NEEDS_PUNYO
def test_punyo_cross_validation_ships_a_model_as_good_as_the_best(tmp_path):
    """Five blocked folds of the 150 frames (a 5-frame gap: the default 30 is a whole block
    here, and vbfe says so): the model each fold ships scores within 5 % of the best single
    method's test MAE, and every method has an interval coverage measured on the folds."""
    clouds = tmp_path / "punyo.clouds.h5"
    _import_punyo(clouds)
    rig = tmp_path / "rig.toml"
    rig.write_text(
        "[train]\nconv_channels = [16, 32, 128]\nn_points = 128\nepochs = 15\nthreads = 1\n"
    )
    model = tmp_path / "punyo.pt"
    args = ("train", str(clouds), "--config", str(rig), "--out", str(model), "--folds", "5")
    result = vbfe(*args, "--gap", "5")
    assert result.returncode == 0, result.stderr
    assert "warning: the gap" not in result.stdout
    summary = load_model(model).record["cross_validation"]["summary"]
    best = min(s["mean_mae_n"] for m, s in summary.items() if m != "selected")
    assert summary["selected"]["mean_mae_n"] <= 1.05 * best, summary
    assert all(0 < s["interval_coverage"] <= 1 for s in summary.values())
