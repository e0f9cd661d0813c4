"""`vbfe reconstruct` on image pairs and sessions: --rectified geometry, depth range derived from
the calibration, maps, and honest warnings (range saturation, no pattern)."""

import cv2
import numpy as np
import pytest

from tests.cli import vbfe as _vbfe
from vbfe.acquire import SessionWriter, finalize_session
from vbfe.common.errors import ReconError
from vbfe.drivers.samples import StereoFrame
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.recon import CloudReader, make_pattern
from vbfe.recon.inputs import find_pairs
from vbfe.recon.maps import read_png_map
from vbfe.truth import calibration_from_rig


def _render(distance_m, pattern=True, seed=0):
    rig = default_rig(640, 360, working_distance_m=distance_m)
    projector = (
        make_pattern(rig.projector.width, rig.projector.height)
        if pattern
        else np.full((rig.projector.height, rig.projector.width, 3), 200, np.uint8)
    )
    rng = np.random.default_rng(seed)
    pair = render_scene(
        rig, TissueSurface(distance_m=distance_m, texture=tissue_texture(rng)), projector, rng=rng
    )
    return rig, pair


def _geometry_args(rig):
    cal = calibration_from_rig(rig)
    return ["--rectified", "--f", cal.f, "--baseline", cal.B * 1e3, "--cx", cal.cx, "--cy", cal.cy]


def test_rendered_png_pair_through_the_cli_gives_the_true_depth(tmp_path):
    rig, pair = _render(0.06)
    cv2.imwrite(str(tmp_path / "scene_left.png"), pair.left)
    cv2.imwrite(str(tmp_path / "scene_right.png"), pair.right)
    result = _vbfe(
        "reconstruct",
        tmp_path / "scene_left.png",
        tmp_path / "scene_right.png",
        *_geometry_args(rig),
        "--maps-dir",
        tmp_path / "maps",
        "--ply-dir",
        tmp_path / "ply",
    )
    assert result.returncode == 0, result.stderr
    assert "pattern decoded" in result.stdout and "density" in result.stdout
    depth = read_png_map(tmp_path / "maps" / "scene_left_depth.png", "depth")
    disparity = read_png_map(tmp_path / "maps" / "scene_left_disparity.png", "disparity")
    covered = pair.valid_left
    both = covered & np.isfinite(depth)
    assert both.sum() > 0.7 * covered.sum()
    assert np.median(np.abs(depth[both] - pair.depth_left_m[both])) < 0.0003  # 0.5 % of 60 mm
    assert np.mean(np.abs(disparity[both] - pair.disparity_left_px[both]) > 1) < 0.01
    with CloudReader(tmp_path / "scene_left.clouds.h5") as clouds:
        assert clouds.attrs["source_kind"] == "images"
        points, _ = clouds.cloud(0)
        assert len(points) == int(np.isfinite(depth).sum())
        assert 0.5 < clouds.frame_table("decoded_fraction")[0] <= 1
    assert (tmp_path / "ply" / "frame_000000.ply").is_file()


def test_rectified_pair_with_offset_principal_points_takes_middlebury_doffs(tmp_path):
    # Crop 8 columns off the right image's left side: its principal point moves 8 px left
    # (Middlebury's doffs = cx_right - cx_left = -8) and every disparity grows by 8 px.
    rig, pair = _render(0.06)
    shift = 8
    right = np.zeros_like(pair.right)
    right[:, :-shift] = pair.right[:, shift:]
    cv2.imwrite(str(tmp_path / "mb_left.png"), pair.left)
    cv2.imwrite(str(tmp_path / "mb_right.png"), right)
    errors = {}
    for doffs in (-shift, 0):
        out = tmp_path / f"doffs{doffs}"
        out.mkdir()
        result = _vbfe(
            "reconstruct",
            tmp_path / "mb_left.png",
            tmp_path / "mb_right.png",
            *_geometry_args(rig),
            "--doffs",
            doffs,
            "--maps-dir",
            out,
            "--out",
            out / "c.clouds.h5",
        )
        assert result.returncode == 0, result.stderr
        depth = read_png_map(out / "mb_left_depth.png", "depth")
        both = pair.valid_left & np.isfinite(depth)
        assert both.sum() > 0.5 * pair.valid_left.sum()
        errors[doffs] = np.median(np.abs(depth[both] - pair.depth_left_m[both]))
    assert errors[-shift] < 0.0003  # as without the crop
    assert errors[0] > 0.005  # read as 8 px more disparity: ~13 mm too near at 60 mm


def test_impossible_rectified_geometry_is_refused(tmp_path):
    rig, pair = _render(0.06)
    for eye, image in (("left", pair.left), ("right", pair.right)):
        cv2.imwrite(str(tmp_path / f"{eye}1.png"), image)
    args = _geometry_args(rig)
    args[args.index("--cx") + 1] = 900.0  # outside the 640 px wide image
    result = _vbfe("reconstruct", tmp_path, *args)
    assert result.returncode == 2
    assert result.stderr.strip().startswith("vbfe reconstruct: error:")
    assert "principal point" in result.stderr and "Traceback" not in result.stderr
    assert not list(tmp_path.glob("*.clouds.h5"))


def test_folder_naming_rules(tmp_path):
    for layout in ("suffix", "prefix", "folders"):
        folder = tmp_path / layout
        names = {
            "suffix": ("a_left.png", "a_right.png", "b_left.png", "b_right.png"),
            "prefix": ("left01.png", "right01.png", "left02.png", "right02.png"),
            "folders": ("left/01.png", "right/01.png", "left/02.png", "right/02.png"),
        }[layout]
        for name in names:
            (folder / name).parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(folder / name), np.zeros((4, 4, 3), np.uint8))
        pairs = find_pairs(folder)
        assert pairs.n_frames == 2
        assert all(
            "left" in str(left) and "right" in str(right)
            for left, right in zip(pairs.lefts, pairs.rights, strict=False)
        )
    (tmp_path / "suffix" / "c_left.png").write_bytes(
        (tmp_path / "suffix" / "a_left.png").read_bytes()
    )
    with pytest.raises(ReconError, match="without their other eye: c"):
        find_pairs(tmp_path / "suffix")


def _session(path, rig, pair):
    height, width = pair.left.shape[:2]
    writer = SessionWriter(
        path, (width, height), calibration_yaml=calibration_from_rig(rig).to_yaml_text()
    )
    writer.append_frames(
        [
            StereoFrame(
                left=pair.left,
                right=pair.right,
                seq=i,
                t_device_ns=i * 33_333_333,
                t_host_ns=1 + i * 33_333_333,
            )
            for i in range(2)
        ]
    )
    writer.close()
    finalize_session(path, {})
    return path


def test_near_scene_session_gets_its_range_from_the_geometry(tmp_path):
    rig, pair = _render(0.027)  # disparities ~68 px: beyond the old fixed 0..63
    covered = pair.valid_left
    assert np.median(pair.disparity_left_px[covered]) > 64
    session = _session(tmp_path / "near.h5", rig, pair)
    result = _vbfe("reconstruct", session, "--workers", 1)
    assert result.returncode == 0, result.stderr
    assert "warning" not in result.stderr
    with CloudReader(tmp_path / "near.clouds.h5") as clouds:
        sgbm = clouds.attrs["sgbm"]
        cal = calibration_from_rig(rig)
        assert sgbm["min_disparity"] == int(np.floor(cal.f * cal.B / 0.120))  # [recon] 120 mm
        assert sgbm["min_disparity"] + sgbm["num_disparities"] > cal.f * cal.B / 0.025
        density = clouds.frame_table("valid_fraction")
        assert np.all(density > 0.7 * covered.mean())
        points, _ = clouds.cloud(0)
        assert abs(np.median(points[:, 2]) - np.median(pair.depth_left_m[covered])) < 0.0003

    shown = _vbfe("inspect", tmp_path / "near.clouds.h5")
    assert shown.returncode == 0, shown.stderr
    lines = shown.stdout.splitlines()
    assert lines[0].startswith(f"{tmp_path / 'near.clouds.h5'}: 2 frames, density")
    assert "frame  density  decoded  at-edge    kept  corrected  rejected" in shown.stdout
    assert len([line for line in lines if line.strip().startswith(("0 ", "1 "))]) == 2

    config = tmp_path / "old.toml"
    config.write_text("[sgbm]\nnum_disparities = 64\n")
    result = _vbfe(
        "reconstruct",
        session,
        "--workers",
        1,
        "--config",
        config,
        "--out",
        tmp_path / "old.clouds.h5",
    )
    assert result.returncode == 0
    assert "of the matched pixels sit at the edge of the disparity range 0..63 px" in result.stderr


def test_half_patterned_pair_is_verified_where_the_pattern_is_and_kept_where_not(tmp_path):
    rig, pair = _render(0.06)
    _, flat = _render(0.06, pattern=False)
    half = pair.left.shape[1] // 2  # the right half of both views without the pattern
    for eye, image, plain in (("left", pair.left, flat.left), ("right", pair.right, flat.right)):
        image = image.copy()
        image[:, half:] = plain[:, half:]
        cv2.imwrite(str(tmp_path / f"half_{eye}.png"), image)
    result = _vbfe("reconstruct", tmp_path, *_geometry_args(rig), "--maps-dir", tmp_path / "m")
    assert result.returncode == 0, result.stderr
    assert "pattern is readable on only" not in result.stderr  # half of it is plenty
    quality = cv2.imread(str(tmp_path / "m" / "half_quality.png"), cv2.IMREAD_UNCHANGED)
    depth = read_png_map(tmp_path / "m" / "half_depth.png", "depth")
    covered = pair.valid_left
    inner = (slice(None), slice(40, half - 40)), (slice(None), slice(half + 80, -40))
    patterned, plain = (quality[side][covered[side]] for side in inner)
    assert np.mean(patterned >= 3) > 0.75 and np.mean(patterned == 2) < 0.01  # verified
    assert np.mean(plain == 2) > 0.7 and np.mean(plain >= 3) < 0.01  # SGBM's, unverified
    assert np.isfinite(depth[covered]).mean() > 0.7  # dense over both halves
    good = np.isfinite(depth) & covered
    assert np.median(np.abs(depth[good] - pair.depth_left_m[good])) < 0.0005
    with CloudReader(tmp_path / "half_left.clouds.h5") as clouds:
        points, _ = clouds.cloud(0)
        verified = clouds.verified(0)
        assert len(verified) == len(points) == int(np.isfinite(depth).sum())
        assert verified.sum() == np.count_nonzero(quality >= 3)
        assert "points verified" in result.stdout


def test_pair_without_the_pattern_warns_once_and_keeps_sgbm_unverified(tmp_path):
    rig, pair = _render(0.06, pattern=False)
    for eye, image in (("left", pair.left), ("right", pair.right)):
        cv2.imwrite(str(tmp_path / f"flat_{eye}.png"), image)
    result = _vbfe("reconstruct", tmp_path, *_geometry_args(rig))
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.splitlines() if "warning" in line]
    assert len(warnings) == 1
    assert warnings[0].startswith(
        "vbfe reconstruct: warning: the De Bruijn pattern is readable on only"
    )
    assert "flagged unverified" in warnings[0] and "use --no-verify" in warnings[0]
    with CloudReader(tmp_path / "flat_left.clouds.h5") as clouds:
        assert clouds.frame_table("valid_fraction")[0] > 0.3  # SGBM's matches, kept
        assert not clouds.verified(0).any()


def test_bad_depth_range_in_the_config_is_a_one_line_error(tmp_path):
    config = tmp_path / "rig.toml"
    config.write_text("[recon]\nmin_depth_mm = 200.0\n")
    (tmp_path / "a_left.png").write_bytes(b"")
    result = _vbfe(
        "reconstruct",
        tmp_path,
        "--config",
        config,
        "--rectified",
        "--f",
        500,
        "--baseline",
        4,
        "--cx",
        10,
        "--cy",
        10,
    )
    assert result.returncode == 2
    assert result.stderr.strip() == (
        "vbfe reconstruct: error: [recon] needs 0 < min_depth_mm < "
        "max_depth_mm, got 200.0 and 120.0"
    )
