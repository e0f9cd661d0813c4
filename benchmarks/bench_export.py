"""MCAP export of a bench session against the time to read it, and its size per image format.

Records a session on the simulated bench (default 8 s of 640×360 at 30 fps, lzf), then in the
same run times reading every frame and force sample through ``SessionReader`` and exporting it
with ``vbfe export --images raw`` (zstd and lz4 chunks), and prints each time with its ratio to
the read (goal: export ≤ 2× read); then exports it with each ``--images`` format (raw, png,
jpeg:90, jpeg:75; lz4 chunks) and prints size, time, the size ratio to raw (goals: png ≥ 3×,
jpeg:90 ≥ 10×) and whether the images decode pixel-identical; then what lossless can reach on
these frames: each lossless encoding OpenCV has (PNG strategies and filters, WebP lossless,
AVIF lossless, and JPEG 2000, which Foxglove cannot show) with its size ratio, bits per sample
and time, and the entropy figures that bound them (the sensor noise's own entropy, the floor
of a PNG predictor, and the residual entropy when predicting from the same image, the
previous frame or the other eye); and the machine load. Run:
``python -m benchmarks.bench_export [--seconds S] [--width W --height H] [--repeats N]``.
"""

from __future__ import annotations

import argparse
import heapq
import math
import os
import tempfile
import time
from functools import partial
from pathlib import Path

import cv2
import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from benchmarks import smoke
from vbfe.acquire import SessionReader, record_session
from vbfe.bags.export import export_mcap
from vbfe.messages.images import image_codec
from vbfe.rig_config import builtin_rig
from vbfe.truth import calibration_from_rig, true_rig


def read_all(path: Path) -> int:
    """Read every frame, force sample and timestamp the export reads; returns bytes read."""
    total = 0
    with SessionReader(path) as reader:
        total += reader.frame_times_ns().nbytes + reader.force_times_ns().nbytes
        total += reader.forces_n().nbytes
        for frame in reader.iter_frames():
            total += frame.left.nbytes + frame.right.nbytes
    return total


def identical(session: Path, mcap: Path) -> bool:
    """Whether every exported left and right image decodes to the session's pixels."""
    with open(mcap, "rb") as fh, SessionReader(session) as reader:
        messages = make_reader(fh, decoder_factories=[DecoderFactory()])
        count = {"left": 0, "right": 0}
        for _, channel, _, image in messages.iter_decoded_messages(log_time_order=False):
            if not channel.topic.startswith("/stereo/") or "image_raw" not in channel.topic:
                continue
            eye = channel.topic.split("/")[2]
            if hasattr(image, "format"):
                pixels = cv2.imdecode(np.frombuffer(bytes(image.data), np.uint8), cv2.IMREAD_COLOR)
            else:
                pixels = np.frombuffer(bytes(image.data), np.uint8).reshape(
                    image.height, image.width, 3
                )
            if not np.array_equal(pixels, getattr(reader.frame(count[eye]), eye)):
                return False
            count[eye] += 1
        return count["left"] == count["right"] == reader.n_frames


def entropy_bits(values: np.ndarray) -> float:
    """Order-0 entropy (bits per sample) of integer ``values`` (residuals mod 256)."""
    counts = np.bincount((np.asarray(values).ravel() % 256).astype(np.int64), minlength=256)
    p = counts[counts > 0] / counts.sum()
    return float(-(p * np.log2(p)).sum())


def rounded_noise(sigma: float) -> np.ndarray:
    """The probabilities of the bench's sensor noise per sample, ``rint(clip(N(0, sigma),
    ±4 sigma))`` (drivers/sim/render.py), for the values -4 sigma … 4 sigma."""
    k = np.arange(-round(4 * sigma), round(4 * sigma) + 1)
    cdf = np.array([0.5 * (1 + math.erf(x / (sigma * math.sqrt(2)))) for x in k + 0.5])
    cdf[-1] = 1.0  # the clip puts the upper tail on the last value
    return np.diff(np.concatenate([[0.0], cdf]))


def huffman_bits(p: np.ndarray) -> float:
    """Mean code length (bits) of the optimal Huffman code of the distribution ``p``."""
    heap = [float(q) for q in p[p > 0]]
    heapq.heapify(heap)
    total = 0.0
    while len(heap) > 1:
        merged = heapq.heappop(heap) + heapq.heappop(heap)
        total += merged  # each merge adds one bit to every symbol under it
        heapq.heappush(heap, merged)
    return total


def distribution_bits(p: np.ndarray) -> float:
    """Entropy (bits) of the distribution ``p``."""
    p = p[p > 0]
    return float(-(p * np.log2(p)).sum())


def med(image: np.ndarray) -> np.ndarray:
    """LOCO-I's median edge detector prediction (JPEG-LS) of each sample from its left, upper
    and upper-left neighbours (the first row and column predicted from what they have)."""
    x = np.pad(image.astype(np.int16), ((1, 0), (1, 0), (0, 0)))
    a, b, c = x[1:, :-1], x[:-1, 1:], x[:-1, :-1]
    return np.where(
        c >= np.maximum(a, b),
        np.minimum(a, b),
        np.where(c <= np.minimum(a, b), np.maximum(a, b), a + b - c),
    )


def lossless_survey(session: Path, every: int) -> None:
    """Each lossless encoding OpenCV has, on every ``every``-th frame of both eyes, and the
    entropy figures that bound what a lossless format can reach on them."""
    with SessionReader(session) as reader:
        sigma = float(reader.metadata.get("bench", {}).get("noise_sigma", 1.0))
        frames = [reader.frame(i) for i in range(0, reader.n_frames, every)]
        following = [reader.frame(i + 1) for i in range(0, reader.n_frames - 1, every)]
    images = [f.left for f in frames] + [f.right for f in frames]
    raw = sum(image.nbytes for image in images)
    png = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY]
    codecs: list[tuple[str, str, list[int]]] = [
        ("png zlib level 1 (before)", ".png", [cv2.IMWRITE_PNG_COMPRESSION, 1]),
        ("png zlib level 9", ".png", [cv2.IMWRITE_PNG_COMPRESSION, 9]),
        (
            "png level 9 filtered",
            ".png",
            [
                cv2.IMWRITE_PNG_COMPRESSION,
                9,
                cv2.IMWRITE_PNG_STRATEGY,
                cv2.IMWRITE_PNG_STRATEGY_FILTERED,
            ],
        ),
        ("png huffman only", ".png", png + [cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]),
        ("png run-length (--images png)", ".png", png + [cv2.IMWRITE_PNG_STRATEGY_RLE]),
    ]
    codecs += [
        (
            f"png run-length filter {name.lower()}",
            ".png",
            png
            + [
                cv2.IMWRITE_PNG_STRATEGY_RLE,
                cv2.IMWRITE_PNG_FILTER,
                getattr(cv2, f"IMWRITE_PNG_FILTER_{name}"),
            ],
        )
        for name in ("SUB", "UP", "AVG", "PAETH")
    ]
    codecs += [
        ("webp lossless", ".webp", [cv2.IMWRITE_WEBP_QUALITY, 101]),
        ("avif lossless", ".avif", [cv2.IMWRITE_AVIF_QUALITY, 100]),
        (
            "avif lossless speed 6",
            ".avif",
            [cv2.IMWRITE_AVIF_QUALITY, 100, cv2.IMWRITE_AVIF_SPEED, 6],
        ),
        (
            "jpeg 2000 lossless (not in Foxglove)",
            ".jp2",
            [cv2.IMWRITE_JPEG2000_COMPRESSION_X1000, 1000],
        ),
    ]
    print(f"lossless on {len(images)} images ({every}th frame of each eye):")
    for name, ext, params in codecs:
        if not cv2.haveImageWriter("x" + ext):
            print(f"  {name:38s} not in this OpenCV build")
            continue
        start, size, same = time.perf_counter(), 0, True
        for image in images:
            data = cv2.imencode(ext, image, params)[1]
            size += data.nbytes
            same = same and np.array_equal(cv2.imdecode(data, cv2.IMREAD_COLOR), image)
        ms = (time.perf_counter() - start) / len(images) * 1e3
        print(
            f"  {name:38s} {raw / size:5.2f}x  {8 * size / raw:5.2f} bits/sample  "
            f"{ms:6.1f} ms/image (with decode)  pixel-identical: {'yes' if same else 'no'}"
        )
    noise = rounded_noise(sigma)
    two = np.convolve(noise, noise)  # a sample minus a neighbour: two noises (-8σ … 8σ)
    half = np.zeros(len(noise))  # floor((n1 + n2) / 2), PNG's avg of two neighbours
    np.add.at(half, np.arange(len(two)) // 2, two)
    ints = [image.astype(np.int16) for image in images]
    lefts, rights = ints[: len(frames)], ints[len(frames) :]
    residuals = {
        "same image, upper neighbour (PNG up)": [x[1:] - x[:-1] for x in ints],
        "same image, LOCO-I median predictor": [x - med(x) for x in ints],
        "previous frame, same eye": [
            getattr(b, eye).astype(np.int16) - getattr(a, eye)
            for a, b in zip(frames, following, strict=False)
            for eye in ("left", "right")
        ],
        "other eye, best shift per frame": [
            min((left[:, d:] - right[:, : right.shape[1] - d] for d in range(64)), key=entropy_bits)
            for left, right in zip(lefts, rights, strict=True)
        ],
    }
    print(f"entropy, bits per sample (the ratio to raw: 8 / bits); sensor noise sigma {sigma:g}:")
    rows = [
        ("the noise itself: no lossless code goes below", distribution_bits(noise)),
        ("flat image, minus one neighbour (PNG up, sub)", distribution_bits(two)),
        ("  the same, Huffman-coded as deflate does", huffman_bits(two)),
        (
            "flat image, minus two neighbours' mean (PNG avg)",
            distribution_bits(np.convolve(noise, half)),
        ),
    ]
    rows += [
        (f"residual: {name}", float(np.mean([entropy_bits(v) for v in values])))
        for name, values in residuals.items()
    ]
    for name, bits in rows:
        print(f"  {name:52s} {bits:5.2f}  ({8 / bits:4.2f}x)")


def best_of(repeats: int, run) -> tuple[float, float]:
    """Shortest wall time and CPU time (all threads) of ``repeats`` runs (the least disturbed
    by other load)."""
    times = []
    for _ in range(repeats):
        start, cpu = time.perf_counter(), time.process_time()
        run()
        times.append((time.perf_counter() - start, time.process_time() - cpu))
    return min(t[0] for t in times), min(t[1] for t in times)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=360)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--every", type=int, default=12, help="the lossless survey takes every N-th frame"
    )
    args = smoke.parse(parser, argv, seconds=0.5, width=320, height=180, repeats=1, every=4)
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / "session.h5"
        config = builtin_rig({"bench": dict(width=args.width, height=args.height)})
        start = time.perf_counter()
        record_session(
            config,
            session,
            duration_s=args.seconds,
            calibration_yaml=calibration_from_rig(true_rig(config)).to_yaml_text(),
        )
        print(
            f"recorded {args.seconds:g} s of {args.width}x{args.height} in "
            f"{time.perf_counter() - start:.1f} s: {session.stat().st_size / 1e6:.0f} MB"
        )
        nbytes = read_all(session)  # warm the page cache before timing
        read_s, read_cpu = best_of(args.repeats, lambda: read_all(session))
        print(
            f"read        wall {read_s:6.2f} s  cpu {read_cpu:6.2f} s  "
            f"({nbytes / 1e6 / read_s:.0f} MB/s decoded)"
        )
        for compression in ("zstd", "lz4"):
            out = Path(tmp) / f"session.{compression}.mcap"
            export_s, export_cpu = best_of(
                args.repeats,
                partial(export_mcap, session, out, None, compression, images=image_codec("raw")),
            )
            print(
                f"export {compression:<4} wall {export_s:6.2f} s  cpu {export_cpu:6.2f} s  "
                f"({out.stat().st_size / 1e6:.0f} MB): wall {export_s / read_s:.2f}x read "
                f"(goal <= 2x), cpu {export_cpu / read_cpu:.2f}x"
            )
        raw_mb = 0.0
        for images in ("raw", "png", "jpeg:90", "jpeg:75"):
            out = Path(tmp) / f"session.{images.replace(':', '')}.mcap"
            wall, cpu = best_of(
                args.repeats, partial(export_mcap, session, out, images=image_codec(images))
            )
            mb = out.stat().st_size / 1e6
            raw_mb = raw_mb or mb
            print(
                f"images {images:<8} wall {wall:6.2f} s  cpu {cpu:6.2f} s  {mb:7.1f} MB  "
                f"{raw_mb / mb:5.1f}x smaller than raw; pixel-identical: "
                f"{'yes' if identical(session, out) else 'no'}"
            )
        lossless_survey(session, args.every)
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
