"""Caspi colour model: crosstalk matrix and offset from flat captures, albedo-free decoding."""

import numpy as np
import pytest

from vbfe.drivers.projector.pattern import fringe_coordinates
from vbfe.recon import ColorModel, ReconError, estimate_color_model, make_pattern
from vbfe.recon.color import color_calibration_patterns
from vbfe.recon.decode import FringeDecoder
from vbfe.truth import calibration_from_rig

K_TRUE = np.array(
    [
        [0.80, 0.15, 0.05],  # camera B <- projector B, G, R
        [0.10, 0.75, 0.15],
        [0.05, 0.20, 0.75],
    ]
)
OFFSET = np.array([14.0, 10.0, 12.0])


def _capture(projected_bgr: np.ndarray, albedo: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Camera image of a projected BGR image (0..255) through crosstalk, albedo, ambient, noise."""
    image = (projected_bgr.astype(np.float64) @ K_TRUE.T) * 0.85 * albedo + OFFSET
    return np.clip(np.rint(image + rng.normal(0, 1.0, image.shape)), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def albedo():
    y, x = np.mgrid[0:120, 0:640]
    return np.stack(
        [0.55 + 0.1 * np.sin(x / 40.0), 0.7 + 0.1 * np.cos(y / 25.0), np.full(x.shape, 0.95)],
        axis=-1,
    )


def test_mixing_matrix_and_offset_are_recovered_despite_albedo(albedo):
    rng = np.random.default_rng(1)
    projections = color_calibration_patterns(albedo.shape[1], albedo.shape[0])
    captures = {name: _capture(image, albedo, rng) for name, image in projections.items()}
    model = estimate_color_model(captures)
    expected = K_TRUE / K_TRUE.sum(axis=1, keepdims=True)
    assert np.abs(model.mixing - expected).max() < 0.02
    assert np.abs(model.offset - OFFSET).max() < 1.0


def test_colour_model_travels_with_the_calibration_file(tmp_path):
    from vbfe.calib.calibration import Calibration
    from vbfe.drivers.sim.rig import default_rig

    model = ColorModel(K_TRUE, OFFSET)
    path = model.apply_to(calibration_from_rig(default_rig(320, 180))).save(tmp_path / "c.yaml")
    loaded = ColorModel.from_calibration(Calibration.load(path))
    np.testing.assert_allclose(loaded.mixing, K_TRUE)
    np.testing.assert_allclose(loaded.offset, OFFSET)


def test_correct_undoes_crosstalk_of_a_flat_colour():
    model = ColorModel(K_TRUE, OFFSET)
    projected = np.array([30.0, 200.0, 90.0])
    image = np.clip(np.rint(K_TRUE @ projected + OFFSET), 0, 255).astype(np.uint8)
    corrected = model.correct(np.broadcast_to(image, (4, 4, 3)).copy())
    assert np.abs(corrected[2, 2] - projected).max() < 1.5


def test_strong_crosstalk_breaks_decoding_unless_corrected(albedo):
    rng = np.random.default_rng(2)
    pattern = make_pattern(640, 120)
    image = _capture(pattern, albedo, rng)
    index, _ = fringe_coordinates(640)
    truth = np.broadcast_to(index, (120, 640))

    def accuracy(model: ColorModel) -> float:
        decoded = FringeDecoder(model).decode(image).index
        readable = decoded >= 0
        return float(np.mean(np.abs(decoded[readable] - truth[readable]) <= 1) * readable.mean())

    corrected = accuracy(ColorModel(K_TRUE / K_TRUE.sum(axis=1, keepdims=True), OFFSET))
    assert corrected > 0.9
    assert corrected > accuracy(ColorModel.identity()) + 0.05


def test_missing_or_dark_captures_are_reported():
    black = np.zeros((20, 20, 3), np.uint8)
    with pytest.raises(ReconError, match="red"):
        estimate_color_model({"blue": black, "green": black, "black": black, "white": black})
    with pytest.raises(ReconError, match="white capture"):
        estimate_color_model({n: black for n in ("blue", "green", "red", "black", "white")})


def test_calibrate_color_fits_the_bench_crosstalk_into_the_calibration(tmp_path):
    import subprocess
    import sys

    from vbfe.calib import Calibration
    from vbfe.drivers.sim.rig import default_rig

    calibration_path = calibration_from_rig(default_rig(640, 360)).save(tmp_path / "cal.yaml")
    config = tmp_path / "rig.toml"
    config.write_text('[bench]\nscene = "plane"\ncrosstalk = 0.3\ndistortion = false\n')
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "vbfe.cli.main",
            "calibrate",
            "color",
            str(calibration_path),
            "--overwrite",
            "--config",
            str(config),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    stored = Calibration.load(calibration_path)
    expected = np.full((3, 3), 0.15)
    np.fill_diagonal(expected, 0.7)  # each channel keeps 1 - 0.3 of its primary
    np.testing.assert_allclose(stored.color_mixing, expected, atol=0.02)
    np.testing.assert_allclose(stored.color_offset, 0.15 * 255, atol=3)  # ambient light
    assert stored.K1 is not None and np.allclose(
        stored.P2, calibration_from_rig(default_rig(640, 360)).P2
    )
