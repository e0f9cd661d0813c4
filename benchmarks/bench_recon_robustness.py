"""Reconstruction under what real tissue and optics do to the pattern, against rendered truth.

For each nuisance knob of the simulated bench (:mod:`vbfe.drivers.sim.nuisance`, plus ambient
light and albedo colour) at three levels, one textured tissue pair is rendered and reconstructed
with SGBM alone and with SGBM + De Bruijn verification; the table gives the density (share of
the truth-covered pixels with a depth), the share of the verified pipeline's points whose match
the code confirmed (the rest are SGBM's, kept where the pattern cannot be read), the median
|Δz| and the bad-pixel rate (|Δd| > 1 px) of each. Under crosstalk the verified pipeline is
also run with a colour model fitted from flat red/green/blue/black/white projections onto a
white plane rendered with the same crosstalk (the bench's colour calibration capture). Run:
``python -m benchmarks.bench_recon_robustness`` (about a minute at 640×360).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks import smoke
from vbfe.drivers.sim.nuisance import Nuisance
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import Plane, TissueSurface, UniformAlbedo, tissue_texture
from vbfe.recon import Reconstructor, estimate_color_model, make_pattern
from vbfe.recon.color import color_calibration_patterns
from vbfe.truth import calibration_from_rig, evaluate_against_truth

DISTANCE_M = 0.06
PINK = (0.72, 0.74, 0.95)  # the bench's default silicone (BGR)
# knob -> three levels, mildest first
KNOBS: dict[str, tuple] = {
    "subsurface_blur_mm": (0.1, 0.2, 0.4),
    "specular": (2.0, 5.0, 10.0),
    "crosstalk": (0.1, 0.2, 0.35),
    "projector_gamma": (1.5, 2.2, 3.0),
    "vignetting": (0.3, 0.5, 0.7),
    "motion_blur_px": (2.0, 4.0, 8.0),
    "ambient": (0.3, 0.5, 0.7),
    "albedo_bgr": ((0.45, 0.5, 0.95), (0.3, 0.35, 0.9), (0.15, 0.2, 0.8)),
}


def render(rig, knob: str | None, level, seed: int = 0):
    """One textured tissue pair with ``knob`` at ``level`` (None: clean)."""
    rng = np.random.default_rng(seed)
    tint = level if knob == "albedo_bgr" else PINK
    surface = TissueSurface(distance_m=DISTANCE_M, texture=tissue_texture(rng, tint_bgr=tint))
    nuisance = Nuisance(**{knob: level}) if knob in Nuisance.__dataclass_fields__ else Nuisance()
    ambient = level if knob == "ambient" else 0.15
    pattern = make_pattern(rig.projector.width, rig.projector.height)
    return render_scene(rig, surface, pattern, rng=rng, ambient=ambient, nuisance=nuisance)


def fitted_color_calibration(rig, calibration, nuisance: Nuisance):
    """The calibration with a colour model fitted from flat projections on a white plane."""
    plane = Plane(np.eye(3), np.array([0.0, 0.0, DISTANCE_M]), texture=UniformAlbedo((1, 1, 1)))
    rng = np.random.default_rng(1)
    captures = {
        name: render_scene(rig, plane, image, rng=rng, nuisance=nuisance).left
        for name, image in color_calibration_patterns(
            rig.projector.width, rig.projector.height
        ).items()
    }
    return estimate_color_model(captures).apply_to(calibration)


def scores(pair, reconstructor: Reconstructor) -> tuple[float, float, float, float]:
    """Density, median |Δz| (mm), bad-pixel rate and verified share of the points of one
    reconstruction."""
    cloud = reconstructor.process(pair.left, pair.right)
    report = evaluate_against_truth(
        cloud, pair.disparity_left_px, pair.depth_left_m, pair.valid_left
    )
    return (
        report.valid_fraction,
        report.median_abs_depth_error_m * 1e3,
        report.bad_pixel_rate,
        float(cloud.verified.mean()) if cloud.verified.size else 0.0,
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=360)
    args = smoke.parse(parser, argv, width=320, height=180)
    start = time.perf_counter()
    rig = default_rig(args.width, args.height, working_distance_m=DISTANCE_M)
    calibration = calibration_from_rig(rig)
    bare = Reconstructor(calibration, verify=False)
    verified = Reconstructor(calibration, verify=True)
    print(
        f"{args.width}x{args.height} textured tissue at {DISTANCE_M * 1e3:.0f} mm, disparity "
        f"range {verified.params.min_disparity}.."
        f"{verified.params.min_disparity + verified.params.num_disparities - 1} px"
    )
    header = (
        f"| {'knob':18s} | {'level':17s} | decoded | density SGBM / +verify | "
        f"verified | median abs dz mm SGBM / +verify | bad px SGBM / +verify |"
    )
    print(header)
    print("|" + "|".join("-" * (len(part)) for part in header.split("|")[1:-1]) + "|")
    rows = [(None, None)] + [(knob, level) for knob, levels in KNOBS.items() for level in levels]
    for knob, level in rows:
        pair = render(rig, knob, level)
        runs = [("", bare, verified)]
        if knob == "crosstalk":
            fitted = fitted_color_calibration(rig, calibration, Nuisance(crosstalk=level))
            runs.append((" +colour fit", bare, Reconstructor(fitted, verify=True)))
        for suffix, plain, checked in runs:
            d0, z0, b0, _ = scores(pair, plain)
            d1, z1, b1, v1 = scores(pair, checked)
            decoded = checked.process(pair.left, pair.right).decoded_fraction
            level_text = (
                "clean"
                if knob is None
                else "/".join(f"{v:.2f}" for v in level)
                if isinstance(level, tuple)
                else f"{level:g}"
            ) + suffix
            print(
                f"| {knob or '-':18s} | {level_text:17s} | {decoded:7.1%} | "
                f"{d0:9.1%} / {d1:6.1%}    | {v1:8.1%} | {z0:14.3f} / {z1:6.3f}          | "
                f"{b0:8.2%} / {b1:6.2%}  |"
            )
    print(f"total {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
