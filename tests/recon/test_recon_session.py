"""Sessions in, point-cloud sidecars out: parallel reconstruction, reader, PLY, CLI."""

import numpy as np
import pytest

from vbfe.acquire import SessionWriter, finalize_session
from vbfe.cli.main import main
from vbfe.common.errors import CalibrationError
from vbfe.drivers.samples import StereoFrame
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import MembraneLoad, TissueSurface, tissue_texture
from vbfe.recon import (
    CloudReader,
    ReconError,
    Reconstructor,
    SgbmParams,
    make_pattern,
    reconstruct_session,
    sidecar_path,
    write_ply,
)
from vbfe.truth import calibration_from_rig

N_FRAMES = 3


def _write_session(path, pairs, calibration_yaml=None):
    height, width = pairs[0][0].shape[:2]
    writer = SessionWriter(path, (width, height), calibration_yaml=calibration_yaml)
    writer.append_frames(
        [
            StereoFrame(
                left=left,
                right=right,
                seq=i,
                t_device_ns=i * 33_333_333,
                t_host_ns=1_000_000 + i * 33_333_333,
            )
            for i, (left, right) in enumerate(pairs)
        ]
    )
    writer.close()
    finalize_session(path, {})
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A short session of a tissue being pulled, with its calibration stored, and the pairs."""
    rig = default_rig(640, 360)
    rng = np.random.default_rng(5)
    tissue = TissueSurface(texture=tissue_texture(rng))
    pattern = make_pattern(rig.projector.width, rig.projector.height)
    pairs = []
    for k in range(N_FRAMES):
        load = MembraneLoad(contact_m=(0.0, 0.0), vector_m=(0.0, 0.0, -0.002 * k), radius_m=0.01)
        pair = render_scene(rig, tissue.with_load(load), pattern, rng=rng)
        pairs.append((pair.left, pair.right))
    calibration = calibration_from_rig(rig)
    folder = tmp_path_factory.mktemp("recon_session")
    path = _write_session(folder / "pull.h5", pairs, calibration.to_yaml_text())
    return path, calibration, pairs


def test_parallel_session_reconstruction_matches_frame_by_frame(recording):
    path, calibration, pairs = recording
    done = []
    out = reconstruct_session(path, workers=2, progress=done.append)
    assert out == sidecar_path(path) == path.with_name("pull.clouds.h5")
    assert sum(done) == N_FRAMES
    reconstructor = Reconstructor(calibration, SgbmParams())
    with CloudReader(out) as clouds:
        assert clouds.n_frames == N_FRAMES
        assert clouds.session_path == path.resolve()
        depths = []
        for i, (left, right) in enumerate(pairs):
            points, colours = clouds.cloud(i)
            expected = reconstructor.process(left, right)
            np.testing.assert_array_equal(points, expected.points)
            np.testing.assert_array_equal(colours, expected.colors)
            near_contact = np.hypot(points[:, 0], points[:, 1]) < 0.003
            depths.append(points[near_contact, 2].mean())
        valid = clouds.frame_table("valid_fraction")
        assert np.all(valid > 0.2)
        counts = clouds.frame_table("match_counts")
        assert np.all(counts[:, 1] > 0)
        assert np.all(np.diff(clouds.frame_table("t_host_ns")) > 0)
    np.testing.assert_allclose(np.diff(depths), -0.002, atol=0.0005)  # pulled 2 mm per frame


def test_session_without_calibration_needs_one(recording, tmp_path):
    _, calibration, pairs = recording
    bare = _write_session(tmp_path / "bare.h5", pairs[:1])
    with pytest.raises(CalibrationError, match="bare.h5.*--calib"):
        reconstruct_session(bare, workers=1)
    yaml_path = calibration.save(tmp_path / "calib.yaml")
    out = reconstruct_session(
        bare, calibration=yaml_path, workers=1, out_path=tmp_path / "clouds.h5"
    )
    with CloudReader(out) as clouds:
        assert clouds.n_frames == 1 and len(clouds.cloud(0)[0]) > 1000


def test_calibration_of_another_resolution_is_refused(recording, tmp_path):
    path, _, _ = recording
    small = calibration_from_rig(default_rig(320, 180))
    with pytest.raises(ReconError, match="640x360.*320x180"):
        reconstruct_session(path, calibration=small, out_path=tmp_path / "never.h5")
    assert not (tmp_path / "never.h5").exists()


def test_cli_reconstructs_and_exports_ply(recording, tmp_path, capsys):
    path, _, _ = recording
    out = tmp_path / "cli.clouds.h5"
    assert (
        main(
            [
                "reconstruct",
                str(path),
                "--out",
                str(out),
                "--workers",
                "1",
                "--ply-dir",
                str(tmp_path / "ply"),
            ]
        )
        == 0
    )
    assert "3 frames" in capsys.readouterr().out
    files = sorted((tmp_path / "ply").glob("*.ply"))
    assert [f.name for f in files] == [f"frame_{i:06d}.ply" for i in range(N_FRAMES)]
    with CloudReader(out) as clouds:
        points, colours = clouds.cloud(2)
    header, _, body = files[2].read_bytes().partition(b"end_header\n")
    assert f"element vertex {len(points)}".encode() in header
    vertices = np.frombuffer(body, dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    np.testing.assert_array_equal(vertices["xyz"], points)
    np.testing.assert_array_equal(vertices["rgb"], colours)


def test_cli_reports_missing_calibration_in_one_line(recording, tmp_path, capsys):
    _, _, pairs = recording
    bare = _write_session(tmp_path / "bare.h5", pairs[:1])
    assert main(["reconstruct", str(bare)]) == 2
    err = capsys.readouterr().err.strip()
    assert "bare.h5" in err
    assert len(err.splitlines()) == 1 and "--calib" in err


def test_reader_refuses_missing_or_foreign_files(tmp_path):
    with pytest.raises(ReconError, match="does not exist"):
        CloudReader(tmp_path / "nothing.clouds.h5")
    with pytest.raises(ReconError, match="points but"):
        write_ply(tmp_path / "x.ply", np.zeros((3, 3)), np.zeros((2, 3)))


def test_interrupted_reconstruction_leaves_no_file(recording, tmp_path):
    path, _, _ = recording
    out = tmp_path / "stopped.clouds.h5"

    def stop(_n):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        reconstruct_session(path, out_path=out, workers=2, progress=stop)
    assert list(tmp_path.iterdir()) == []
