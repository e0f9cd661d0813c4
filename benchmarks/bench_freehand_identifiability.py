"""How well an ideal observer could read force from shape on freehand trials, per stiffness range.

For each range of ``freehand_stiffness_n_per_m``, 40 freehand trials (seeds 0–39); every 0.1 s
the true visible displacement of the grasped point (``deformation_scale × u``) and the spread of
the deformation (its radius) are taken as a perfect observer would see them, and force is
predicted by 15-nearest-neighbour regression fitted on trials 0–29 and scored on 30–39, beside
the mean predictor. No images are rendered: this is the floor any image-based model meets on
the bench. A second floor sees only the depth (z) component of that displacement, as a
depth-change image does: the pull's elevation (20–50° per trial) then scales what is seen.
Run: ``python -m benchmarks.bench_freehand_identifiability``.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree

from benchmarks import smoke
from vbfe.drivers.sim import SimBench

RANGES = ((40.0, 200.0), (60.0, 110.0), (70.0, 95.0), (75.0, 90.0), (80.0, 80.0))


def observations(stiffness_range: tuple[float, float], seeds: range) -> np.ndarray:
    """Rows (trial, visible displacement m, radius m, force N, its depth component m) every
    0.1 s of each trial."""
    rows = []
    for seed in seeds:
        bench = SimBench(
            seed=seed,
            protocol="freehand",
            width=64,
            height=36,
            freehand_stiffness_n_per_m=stiffness_range,
        )
        t = np.arange(0.0, bench.duration_s(), 0.1)
        u, force, _ = bench.trial.protocol.state(t)
        visible = bench.trial.deformation_scale * u
        depth = visible * abs(bench.trial.sample.pull_direction[2])
        rows.append(
            np.column_stack(
                [
                    np.full(len(t), seed),
                    visible,
                    np.full(len(t), bench.trial.radius_m()),
                    force,
                    depth,
                ]
            )
        )
    return np.concatenate(rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=40, help="per range; the last quarter scored")
    parser.add_argument("--ranges", type=int, default=len(RANGES), help="the first N ranges")
    args = smoke.parse(parser, argv, trials=8, ranges=1)
    n_train = args.trials * 3 // 4
    print(
        "stiffness range (N/m) | ideal observer MAE (N) | depth component only (N) | "
        "mean predictor MAE (N)"
    )
    scale = np.array([0.003, 0.015])  # typical displacement and radius (m)
    for low, high in RANGES[: args.ranges]:
        data = observations((low, high), range(args.trials))
        train, test = data[data[:, 0] < n_train], data[data[:, 0] >= n_train]
        floors = []
        for displacement in (1, 4):  # the whole visible displacement, its depth component
            columns = [displacement, 2]
            _, index = cKDTree(train[:, columns] / scale).query(test[:, columns] / scale, k=15)
            floors.append(np.abs(train[index, 3].mean(axis=1) - test[:, 3]).mean())
        mean = np.abs(train[:, 3].mean() - test[:, 3]).mean()
        print(f"{low:g}-{high:g} | {floors[0]:.3f} | {floors[1]:.3f} | {mean:.3f}")


if __name__ == "__main__":
    main()
