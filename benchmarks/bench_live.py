"""Live estimation on the simulated bench: achieved estimate rate and latency per stage.

For each resolution a stereo endoscope delivers 30 fps in real time and ``vbfe live``'s
pipeline (reconstruct -> prepare -> model, each stage on its own thread, the newest frame
winning; reconstruct and prepare on one thread for the texture model) turns the newest frames
into forces with the demo's PointNet (32-64-256 on 1024 points with the rest depth change;
untrained weights: speed does not depend on them). Prints
estimates/s, p50/p95 latency from frame capture (host time) to estimate, the share of frames
skipped, the median of each stage, the CPU the run used (cores), and the OpenCV and torch
thread counts; recording, the frames the file holds and those it lost (``lost: queue``: the
recorder's queue was full; ``device``: the camera side lost them).

``--background-load N`` runs every configuration twice, without and then beside N busy
processes (a lab PC also runs the recorder and the viewer); ``--record`` adds runs that also
record the session (HDF5, as ``vbfe live --record``). ``--foxglove`` runs every configuration
``--repeats`` times without and with ``vbfe live --foxglove``'s server (JPEG 90 images, a
WebSocket client on loopback subscribed to every topic, as the Foxglove app would be),
alternating, and prints the median estimate rate with the server over the rate without (goal:
within 5 %). ``--model hooke_texture`` runs Hooke's law on the 3D displacement tracked in the
tissue's texture instead of the PointNet (the bench's tissue textured; goal at 640×360: at
least 25 est/s, p95 latency at most 80 ms beside one busy process); the live path then computes
the texture's displacement alone, and ``--novelty`` gives the model a flag of frames outside
the training data (as ``vbfe train`` stores), which reads every feature. ``--scale``,
``--row-scale`` and the thread counts default to the ``[live]`` table, as in ``vbfe live``. The
endoscope is the real OpenCV camera driver reading a capture that replays frames the bench
rendered beforehand, paced on the host clock: a real endoscope's frames cost the host nothing
to make, while the bench's live rendering would take a large share of the two cores
(``--render-live`` measures that instead). Run: ``python -m benchmarks.bench_live [--seconds S]
[--scale 1.0] [--row-scale 1.0] [--background-load 1] [--record [--compression blosc-lz4]]
[--sizes 640x360,1280x720] [--render-live] [--foxglove [--repeats 3]] [--model
hooke_texture [--novelty]]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from pathlib import Path

import cv2
import numpy as np
import torch

from benchmarks import smoke
from tests.foxglove_client import FoxgloveClient
from vbfe.acquire import Acquisition, SessionReader
from vbfe.acquire.recording.record import session_recorder
from vbfe.acquire.session.extra_streams import marks_stream
from vbfe.drivers.camera.opencv import OpenCVStereoCamera
from vbfe.drivers.pacing import sleep_until
from vbfe.drivers.projector.pattern import make_pattern
from vbfe.drivers.registry import open_rig
from vbfe.drivers.rig import Rig, RigOptions
from vbfe.estimate.baselines import AffineBaseline
from vbfe.estimate.candidates import CANDIDATES, TEXTURE_FEATURE, NetworkEstimator
from vbfe.estimate.model_file import ForceModel
from vbfe.estimate.novelty import THUMB_CELLS, K, NoveltyFlag
from vbfe.estimate.pointnet import PointNetRegressor
from vbfe.estimate.train_config import TrainConfig
from vbfe.live.estimator import STAGES, FrameEstimator
from vbfe.live.foxglove_server import LIVE_IMAGES, FoxgloveServer
from vbfe.live.run import LiveRun, run_headless, use_threads
from vbfe.rig_config import RigConfig, builtin_rig
from vbfe.truth import calibration_from_rig, true_rig

SIZES = ((640, 360), (1280, 720))
FPS = 30.0
REPLAY_FRAMES = 60  # rendered once, replayed in a loop


class ReplayCapture:
    """The ``cv2.VideoCapture`` surface of a side-by-side endoscope that replays given frames
    at ``fps`` on the host clock (device time = the frame's due time)."""

    def __init__(self, frames: list[np.ndarray], fps: float) -> None:
        self.frames, self.period_ns = frames, 1e9 / fps
        self.fps, self._start_ns, self._seq = fps, time.monotonic_ns(), -1

    def isOpened(self) -> bool:
        return True

    def grab(self) -> bool:
        self._seq += 1
        sleep_until(self._start_ns + round(self._seq * self.period_ns))
        return True

    def retrieve(self) -> tuple[bool, np.ndarray]:
        return True, self.frames[self._seq % len(self.frames)]

    def read(self) -> tuple[bool, np.ndarray]:
        return self.retrieve() if self.grab() else (False, None)

    def get(self, prop: int) -> float:
        height, width = self.frames[0].shape[:2]
        values = {
            cv2.CAP_PROP_FRAME_WIDTH: width,
            cv2.CAP_PROP_FRAME_HEIGHT: height,
            cv2.CAP_PROP_FPS: self.fps,
            cv2.CAP_PROP_POS_MSEC: (self._start_ns + self._seq * self.period_ns) / 1e6,
        }
        return float(values.get(prop, 0.0))

    def set(self, prop: int, value: float) -> bool:
        return True

    def release(self) -> None:
        pass


def rendered_frames(config: RigConfig, n: int) -> list[np.ndarray]:
    """``n`` side-by-side frames of the bench's trial, rendered as fast as the bench can."""
    with open_rig(config, RigOptions(realtime=False), ("camera",)) as rig:
        frames = [rig.camera.read(5.0) for _ in range(n)]
    return [np.hstack([f.left, f.right]) for f in frames]


def replay_rig(config: RigConfig, frames: list[np.ndarray]) -> Rig:
    """The bench's trocar and projector with a replaying endoscope in place of its camera."""
    rig = open_rig(config, RigOptions(realtime=True))
    height, width = frames[0].shape[0], frames[0].shape[1] // 2
    camera = OpenCVStereoCamera(
        device="replay",
        width=width,
        height=height,
        fps=FPS,
        fourcc="YUYV",
        capture_factory=lambda device: ReplayCapture(frames, FPS),
    )
    rig.replace("camera", camera)
    return rig


def untrained_model(conv_channels: list[int]) -> ForceModel:
    """A PointNet of the given width with the default [train] settings (1024 points, depth
    change against the run's first cloud)."""
    config = TrainConfig(conv_channels=conv_channels)
    network = PointNetRegressor(
        conv_channels=conv_channels,
        head_channels=config.head_channels,
        rest_depth=config.rest_depth,
    )
    return ForceModel(
        config=config,
        selected="pointnet",
        estimators={"pointnet": NetworkEstimator(network.eval(), config.n_points)},
    )


def texture_model(stiffness_n_per_m: float = 900.0, novelty: bool = False) -> ForceModel:
    """Hooke's law on the texture's 3D displacement (speed does not depend on the slope); with
    ``novelty`` a flag of frames outside the training data (``vbfe train`` stores one), which
    reads every feature of each frame, not only the texture's."""
    name = CANDIDATES["hooke_texture"]
    hooke = AffineBaseline(name, np.array([stiffness_n_per_m]), np.array([0.0]), TEXTURE_FEATURE)
    flag = NoveltyFlag(np.zeros((K, THUMB_CELLS**2 + 2)), np.inf, True) if novelty else None
    return ForceModel(
        config=TrainConfig(model="hooke_texture"),
        selected=name,
        estimators={name: hooke},
        novelty=flag,
    )


def busy_processes(n: int) -> list[subprocess.Popen]:
    """``n`` processes that each keep one core busy until killed."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


@contextmanager
def watching(server: FoxgloveServer) -> Iterator[dict[str, int]]:
    """A client subscribed to every topic of a started ``server``, reading in a thread until
    the block ends; yields its message counts by topic."""
    counts: dict[str, int] = {}
    done = threading.Event()

    def watch() -> None:
        with FoxgloveClient("127.0.0.1", server.port) as client:
            client.wait_for_topics({"/trocar/wrench", "/vbfe/estimate"})
            client.subscribe(list(client.channels))
            while not done.is_set() and not client.closed:
                for channel, _, _ in client.messages(0.5):
                    counts[channel["topic"]] = counts.get(channel["topic"], 0) + 1

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    try:
        yield counts
    finally:
        done.set()
        thread.join()


def measure(
    config: RigConfig,
    frames: list[np.ndarray] | None,
    seconds: float,
    scale: float,
    row_scale: float,
    model: ForceModel,
    record: Path | None,
    foxglove: bool = False,
    depth_margin_mm: float = 0.0,
) -> dict[str, float]:
    """Run live estimation on a real-time bench for ``seconds`` (replaying ``frames``, or
    rendering live when None), recording into ``record`` when given, served to a Foxglove
    client when ``foxglove``."""
    rig = (
        open_rig(config, RigOptions(realtime=True))
        if frames is None
        else replay_rig(config, frames)
    )
    calibration = calibration_from_rig(true_rig(config))
    estimator = FrameEstimator(
        model,
        calibration,
        config.sgbm,
        scale=scale,
        row_scale=row_scale,
        depth_margin_mm=depth_margin_mm,
    )
    acquisition = (
        session_recorder(config, record, rig, streams=(marks_stream(),))
        if record
        else Acquisition(rig, pattern=make_pattern)
    )
    server = FoxgloveServer(0, LIVE_IMAGES, target="magnitude") if foxglove else None
    run = LiveRun(
        acquisition,
        estimator,
        outputs=(server,) if server is not None else (),
        max_frame_age_s=config.live.max_frame_age_s,
    )
    run.start()
    with watching(server) if server is not None else nullcontext({}) as viewer:
        cpu0, wall0 = time.process_time(), time.monotonic()
        status = run_headless(run, seconds, lambda s: None)
        cores = (time.process_time() - cpu0) / (time.monotonic() - wall0)
    if run.error:
        raise SystemExit(f"live run failed: {run.error}")
    if server is not None:
        print(
            "  the Foxglove client received "
            + ", ".join(f"{n} {topic}" for topic, n in sorted(viewer.items()))
            + f"; {server.frames_skipped} frames skipped for it"
        )
    lost = {"queue": float("nan"), "device": float("nan"), "frames": float("nan")}
    if record is not None:  # what the file lost: the writer's queue full, the camera's side
        with SessionReader(record) as reader:
            lost = {
                "queue": reader.attrs["camera_queue_dropped"],
                "device": reader.attrs["camera_device_dropped"],
                "frames": reader.n_frames,
            }
    if len(run.estimates) < 2:  # e.g. every frame came later than [live] max_frame_age_s
        return {
            **lost,
            "rate": 0.0,
            "p50": float("nan"),
            "p95": float("nan"),
            "cores": cores,
            "skipped": status.skipped / max(status.frames, 1),
            **{name: float("nan") for name in STAGES},
        }
    settled = run.estimates[0].t_ready_host_ns + 1e9  # the first second includes warm-up
    estimates = [e for e in run.estimates if e.t_frame_host_ns >= settled]
    stages = np.array([e.stage_s for e in estimates]) * 1e3
    latency = np.array([e.latency_s for e in estimates]) * 1e3
    span_s = (estimates[-1].t_ready_host_ns - estimates[0].t_ready_host_ns) / 1e9
    return {
        **lost,
        "rate": (len(estimates) - 1) / span_s,
        "p50": float(np.percentile(latency, 50)),
        "p95": float(np.percentile(latency, 95)),
        "skipped": status.skipped / status.frames,
        "cores": cores,
        **{name: float(np.median(stages[:, k])) for k, name in enumerate(STAGES)},
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--scale", type=float, default=None, help="default: [live] scale")
    parser.add_argument(
        "--depth-margin-mm",
        type=float,
        help="default: [live] depth_margin_mm (0: search the whole [recon] depth range)",
    )
    parser.add_argument("--row-scale", type=float, default=None, help="default: [live] row_scale")
    parser.add_argument("--sizes", default="640x360,1280x720")
    parser.add_argument(
        "--background-load",
        type=int,
        default=0,
        metavar="N",
        help="also run each configuration beside N busy processes",
    )
    parser.add_argument(
        "--record", action="store_true", help="also run each configuration recording the session"
    )
    parser.add_argument(
        "--compression", default=None, help="of the recorded frames (default: [record] compression)"
    )
    parser.add_argument(
        "--foxglove",
        action="store_true",
        help="compare each configuration with and without the Foxglove server (and a client)",
    )
    parser.add_argument(
        "--repeats", type=int, default=3, help="--foxglove: runs of each, alternating"
    )
    parser.add_argument(
        "--paper-network",
        action="store_true",
        help="PointNet 64-128-1024 instead of the demo's 32-64-256",
    )
    parser.add_argument(
        "--model",
        choices=("pointnet", "hooke_texture"),
        default="pointnet",
        help="hooke_texture: Hooke's law on the texture's 3D displacement (textured tissue)",
    )
    parser.add_argument(
        "--novelty",
        action="store_true",
        help="hooke_texture: the model carries a novelty flag (every feature of every frame)",
    )
    parser.add_argument(
        "--render-live",
        action="store_true",
        help="the bench camera renders every frame in real time (costs CPU)",
    )
    parser.add_argument(
        "--opencv-threads",
        type=int,
        default=None,
        help="default: [live] opencv_threads (0: one per core)",
    )
    args = smoke.parse(parser, argv, seconds=4.0, sizes="320x180", repeats=1)
    settings = builtin_rig().live
    args.scale = args.scale or settings.scale
    args.row_scale = args.row_scale or settings.row_scale
    if args.depth_margin_mm is None:
        args.depth_margin_mm = settings.depth_margin_mm
    if args.opencv_threads is not None:
        settings = dataclasses.replace(settings, opencv_threads=args.opencv_threads)
    use_threads(settings)
    channels = [64, 128, 1024] if args.paper_network else [32, 64, 256]
    sizes = [tuple(int(v) for v in size.split("x")) for size in args.sizes.split(",")]
    compression = args.compression or builtin_rig().record.compression
    print(
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; "
        + (
            "Hooke's law on the texture's 3D displacement (textured tissue"
            + (", novelty flag)" if args.novelty else ")")
            if args.model == "hooke_texture"
            else f"PointNet {'-'.join(map(str, channels))}"
        )
        + f", reconstruction at scale {args.scale}, rows "
        f"{args.row_scale}, depth margin {args.depth_margin_mm:g} mm, "
        f"{'bench rendering live' if args.render_live else 'replayed bench frames'}"
        f" at {FPS:.0f} fps; OpenCV threads {cv2.getNumThreads()}, torch threads "
        f"{torch.get_num_threads()}; stages reconstruct -> prepare -> model on their own "
        f"threads (reconstruct+prepare on one for the texture model); recording compression "
        f"{compression}"
    )
    print(
        f"{'camera':>10} {'record':>6} {'busy':>4} {'fox':>3} {'est/s':>6} {'p50 ms':>7} "
        f"{'p95 ms':>7} "
        f"{'skipped':>7} {'cores':>5} "
        + " ".join(f"{s + ' ms':>14}" for s in STAGES)
        + f" {'frames':>6} {'lost: queue':>11} {'device':>6}"
    )
    model = (
        texture_model(novelty=args.novelty)
        if args.model == "hooke_texture"
        else untrained_model(channels)
    )
    loads = [0] + ([args.background_load] if args.background_load else [])
    with tempfile.TemporaryDirectory() as folder:
        for width, height in sizes:
            bench = dict(width=width, height=height, fps=FPS)
            if args.model == "hooke_texture":
                bench["textured"] = True
            config = builtin_rig({"bench": bench, "record": {"compression": compression}})
            frames = None if args.render_live else rendered_frames(config, REPLAY_FRAMES)
            foxglove = [False, True] * args.repeats if args.foxglove else [False]
            for record in [False] + ([True] if args.record else []):
                for load in loads:
                    rates: dict[bool, list[float]] = {False: [], True: []}
                    for k, fox in enumerate(foxglove):
                        busy = busy_processes(load)
                        try:
                            path = Path(folder) / f"live-{width}-{record}-{load}-{k}.h5"
                            r = measure(
                                config,
                                frames,
                                args.seconds,
                                args.scale,
                                args.row_scale,
                                model,
                                path if record else None,
                                fox,
                                args.depth_margin_mm,
                            )
                        finally:
                            for process in busy:
                                process.kill()
                                process.wait()
                        rates[fox].append(r["rate"])
                        print(
                            f"{width:>5}x{height:<4} {'yes' if record else 'no':>6} {load:>4} "
                            f"{'on' if fox else 'off':>3} {r['rate']:6.1f} {r['p50']:7.1f} "
                            f"{r['p95']:7.1f} {r['skipped']:7.0%} "
                            f"{r['cores']:5.2f} "
                            + " ".join(f"{r[s]:14.1f}" for s in STAGES)
                            + f" {r['frames']:6.0f} {r['queue']:11.0f} {r['device']:6.0f}",
                            flush=True,
                        )
                    if args.foxglove:
                        on, off = np.median(rates[True]), np.median(rates[False])
                        print(
                            f"  Foxglove server on / off: median {on:.2f} / {off:.2f} est/s = "
                            f"{on / off:.3f} (goal >= 0.95)",
                            flush=True,
                        )
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
