"""Live estimation on the simulated bench: achieved estimate rate and latency per stage.

For each resolution the bench camera runs in real time at 30 fps (rendering costs CPU here
that a real endoscope does not), the newest frame is reconstructed (SGBM + De Bruijn
verification) and a PointNet (untrained weights: speed does not depend on them) estimates the
force. Prints estimates/s, p50/p95 latency from frame capture (host time) to estimate, the
median of each stage, and the share of frames skipped. Run:
``python benchmarks/bench_live.py [--seconds S] [--scale 1.0]``.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import torch

from vbfe.config import load_config, section
from vbfe.drivers.registry import open_devices
from vbfe.estimate.model_file import ForceModel
from vbfe.estimate.pointnet import PointNetRegressor
from vbfe.estimate.train_config import TrainConfig
from vbfe.live.estimator import STAGES, FrameEstimator
from vbfe.live.run import LiveRun, run_headless
from vbfe.recon import SgbmParams
from vbfe.truth import calibration_from_rig, true_rig

SIZES = ((640, 360), (1280, 720))


def untrained_model(conv_channels: list[int]) -> ForceModel:
    """A PointNet of the given width with the default [train] settings (1024 points)."""
    config = TrainConfig(conv_channels=conv_channels)
    network = PointNetRegressor(conv_channels=conv_channels, head_channels=config.head_channels)
    return ForceModel(network=network.eval(), config=config, baselines={})


def measure(width: int, height: int, seconds: float, scale: float,
            conv_channels: list[int]) -> dict[str, float]:
    """Run live estimation on a real-time bench of this size for ``seconds``."""
    config = load_config()
    config["bench"].update(width=width, height=height, fps=30.0, realtime=True)
    devices = open_devices(config)
    calibration = calibration_from_rig(true_rig(config))
    estimator = FrameEstimator(untrained_model(conv_channels), calibration,
                               SgbmParams.from_config(section(config, "sgbm")), scale=scale)
    run = LiveRun(devices, estimator)
    run.start()
    status = run_headless(run, seconds, lambda s: None)
    estimates = run.estimates[5:]  # the first few include warm-up
    stages = np.array([e.stage_s for e in estimates]) * 1e3
    latency = np.array([e.latency_s for e in estimates]) * 1e3
    span_s = (estimates[-1].t_ready_host_ns - estimates[0].t_ready_host_ns) / 1e9
    return {"rate": (len(estimates) - 1) / span_s, "p50": float(np.percentile(latency, 50)),
            "p95": float(np.percentile(latency, 95)), "skipped": status.skipped / status.frames,
            **{name: float(np.median(stages[:, k])) for k, name in enumerate(STAGES)}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--paper-network", action="store_true",
                        help="PointNet 64-128-1024 instead of the demo's 32-64-256")
    args = parser.parse_args()
    torch.set_num_threads(1)
    channels = [64, 128, 1024] if args.paper_network else [32, 64, 256]
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; PointNet "
          f"{'-'.join(map(str, channels))}, reconstruction at scale {args.scale}")
    print(f"{'camera':>10} {'est/s':>6} {'p50 ms':>7} {'p95 ms':>7} {'skipped':>8} "
          + " ".join(f"{s + ' ms':>14}" for s in STAGES))
    for width, height in SIZES:
        r = measure(width, height, args.seconds, args.scale, channels)
        print(f"{width:>5}x{height:<4} {r['rate']:6.1f} {r['p50']:7.1f} {r['p95']:7.1f} "
              f"{r['skipped']:8.0%} " + " ".join(f"{r[s]:14.1f}" for s in STAGES))


if __name__ == "__main__":
    main()
