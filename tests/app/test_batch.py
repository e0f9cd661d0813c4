"""Datasets of many sessions: the manifest, batch reconstruction on a local pool and on Ray,
and sessions that fail or kill their worker without stopping the others."""

import csv
import os

import numpy as np
import pytest

from tests.cli import vbfe
from vbfe.acquire import record_session
from vbfe.acquire.session.inspect import inspect_session
from vbfe.batch.executors import run_tasks
from vbfe.batch.manifest import read_manifest
from vbfe.recon import CloudReader, sidecar_path
from vbfe.rig_config import builtin_rig
from vbfe.truth import calibration_from_rig, true_rig

CONDITIONS = [(40.0, 0.01), (80.0, 0.005), (200.0, 0.002)]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three short bench sessions (320x180, 0.5 s) with their calibration, in nested folders."""
    root = tmp_path_factory.mktemp("dataset")
    sessions = []
    for k, (stiffness, speed) in enumerate(CONDITIONS):
        config = builtin_rig(
            {
                "bench": dict(
                    width=320,
                    height=180,
                    fps=10.0,
                    seed=k,
                    distortion=False,
                    stiffness_n_per_m=stiffness,
                    pull_speed_m_per_s=speed,
                )
            }
        )
        calibration = calibration_from_rig(true_rig(config))
        folder = root / f"day{k % 2}"
        folder.mkdir(exist_ok=True)
        path = folder / f"k{int(stiffness)}.h5"
        record_session(
            config,
            path,
            duration_s=0.5,
            operator="ana",
            calibration_yaml=calibration.to_yaml_text(),
        )
        sessions.append(path)
    return root, sessions


def test_dataset_lists_sessions_and_writes_a_manifest(dataset, tmp_path):
    root, sessions = dataset
    (root / "day1" / "broken.h5").write_bytes(b"not an HDF5 file at all")
    try:
        manifest = root / "manifest.csv"
        result = vbfe("dataset", root, "--manifest", manifest)
        assert result.returncode == 1, result.stderr  # one session is unreadable
        assert "4 sessions, 0 with current clouds, 1 unreadable" in result.stdout
        with open(manifest, newline="") as f:
            rows = {row["path"]: row for row in csv.DictReader(f)}
        assert sorted(rows) == ["day0/k200.h5", "day0/k40.h5", "day1/broken.h5", "day1/k80.h5"]
        assert rows["day1/broken.h5"]["status"].startswith("unreadable:")
        k80 = rows["day1/k80.h5"]
        assert k80["status"] == "complete" and k80["operator"] == "ana"
        assert "stiffness_n_per_m=80.0" in k80["condition"]
        assert int(k80["frames"]) == 5 and int(k80["frame_drops"]) == 0
        assert float(k80["duration_s"]) == round(inspect_session(sessions[1]).duration_s, 3) > 0.4
        assert k80["clouds"] == "missing" and len(k80["calibration_hash"]) == 12
        # an existing manifest is kept unless --overwrite
        again = vbfe("dataset", root, "--manifest", manifest)
        assert again.returncode == 2 and "--overwrite" in again.stderr
    finally:
        (root / "day1" / "broken.h5").unlink()
    assert read_manifest(manifest)[0] == root / "day0" / "k200.h5"


def _clouds(session):
    with CloudReader(sidecar_path(session)) as clouds:
        return [clouds.cloud(i)[0] for i in range(clouds.n_frames)]


@pytest.mark.slow
def test_local_pool_and_ray_give_the_same_clouds_and_skip_current_ones(dataset, tmp_path):
    root, sessions = dataset
    manifest = tmp_path / "all.csv"
    assert vbfe("dataset", root, "--manifest", manifest).returncode == 0
    local = vbfe("reconstruct", manifest, "--executor", "local", "--workers", "2")
    assert local.returncode == 0, local.stderr
    assert local.stdout.count("reconstructed, ") == 3 and local.stdout.count(": 5 frames") == 3
    first = {s: _clouds(s) for s in sessions}
    assert all(len(c) == 5 and sum(len(p) for p in c) > 0 for c in first.values())
    rerun = vbfe("reconstruct", *sessions)
    assert rerun.returncode == 0 and rerun.stdout.count("up to date") == 3
    listed = vbfe("dataset", root)
    assert "3 sessions, 3 with current clouds, 0 unreadable" in listed.stdout
    pytest.importorskip("ray")
    ray_run = vbfe("reconstruct", manifest, "--executor", "ray", "--workers", "2", "--overwrite")
    assert ray_run.returncode == 0, ray_run.stderr
    assert ray_run.stdout.count("reconstructed, ") == 3 and "on ray" in ray_run.stdout
    for session in sessions:
        for a, b in zip(first[session], _clouds(session), strict=False):
            np.testing.assert_array_equal(a, b)


@pytest.fixture(scope="module")
def pulls(tmp_path_factory):
    """Two 3 s bench sessions with a whole pull (rest, pull, hold) for the sync check."""
    folder = tmp_path_factory.mktemp("pulls")
    paths = []
    for seed in (1, 2):
        config = builtin_rig(
            {
                "bench": dict(
                    width=320,
                    height=180,
                    fps=15.0,
                    seed=seed,
                    distortion=False,
                    stiffness_n_per_m=200.0,
                    pull_speed_m_per_s=0.01,
                    hold_s=1.0,
                )
            }
        )
        paths.append(folder / f"pull{seed}.h5")
        record_session(config, paths[-1], duration_s=3.0)
    return paths


def test_a_failing_session_is_named_and_the_others_finish(pulls, tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + os.urandom(2000))
    result = vbfe("verify-sync", pulls[0], bad, pulls[1], "--workers", "2")
    assert result.returncode == 2
    assert f"{bad}: FAILED:" in result.stdout
    for good in pulls:  # both good sessions were checked and their result stored
        assert f"{good}: PASS offset" in result.stdout or f"{good}: FAIL offset" in result.stdout
        assert good.with_suffix(".sync.png").exists()
    again = vbfe("verify-sync", *pulls)
    assert again.stdout.count("(up to date)") == 2, again.stdout
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("vbfe verify-sync: error: 1 of 3 sessions failed: bad.h5")
    assert "Traceback" not in result.stderr


def _die_on_b(item):
    if item == "b":
        os.kill(os.getpid(), 9)
    return item.upper()


def test_a_killed_worker_fails_only_its_own_task():
    outcomes = {o.item: o for o in run_tasks(_die_on_b, ["a", "b", "c", "d"], workers=2)}
    assert {k: o.ok for k, o in outcomes.items()} == {"a": True, "b": False, "c": True, "d": True}
    assert outcomes["b"].error == "worker killed by signal SIGKILL"
    assert [outcomes[k].value for k in "acd"] == ["A", "C", "D"]


def test_batch_misuse_is_a_one_line_error(dataset):
    root, sessions = dataset
    result = vbfe("reconstruct", *sessions, "--executor", "local", "--out", "x.h5")
    assert result.returncode == 2
    assert "--out, --ply-dir, --maps-dir, --rectified and --truth take one input" in result.stderr
    missing = vbfe("verify-sync", root / "nope.h5", sessions[0])
    assert missing.returncode == 2 and "not found" in missing.stderr and "nope.h5" in missing.stderr
