"""Reconstruct every frame of a recorded session into a point-cloud sidecar, in parallel."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import signal
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from vbfe import __version__
from vbfe.acquire import SessionReader
from vbfe.calib.calibration import Calibration, load_calibration
from vbfe.recon.clouds import COUNT_COLUMNS, CloudWriter, sidecar_path
from vbfe.recon.errors import ReconError
from vbfe.recon.freshness import fingerprint_of
from vbfe.recon.matching import SgbmParams
from vbfe.recon.triangulate import Reconstructor

FrameResult = tuple[int, np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]

_worker: dict[str, object] = {}  # per-process state: the session reader and reconstructor


def _init_worker(session_path: str, calibration_yaml: str, params: dict, verify: bool,
                 threads: int, ignore_interrupt: bool = False) -> None:
    """Open the session and build the reconstructor once per worker process (child processes
    leave Ctrl-C to the parent, which stops the pool)."""
    if ignore_interrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    cv2.setNumThreads(threads)
    _worker["reader"] = SessionReader(session_path)
    _worker["reconstructor"] = Reconstructor(Calibration.from_yaml_text(calibration_yaml),
                                             SgbmParams(**params), verify=verify)


def _process_frame(i: int) -> FrameResult:
    """Reconstruct frame ``i`` of the worker's session; returns the cloud and its statistics."""
    frame = _worker["reader"].frame(i)
    cloud = _worker["reconstructor"].process(frame.left, frame.right)
    d = cloud.disparity[cloud.valid]
    stats = (np.array([d.min(), np.median(d), d.max(), d.mean()], np.float32) if d.size
             else np.full(4, np.nan, np.float32))
    counts = np.array([cloud.counts.get(k, -1) for k in COUNT_COLUMNS], np.int64)
    return i, cloud.points, cloud.colors, float(cloud.valid.mean()), stats, counts


def resolve_calibration(session_path: str | Path,
                        calibration: Calibration | str | Path | None = None) -> Calibration:
    """The calibration to use: the given object, a YAML/session path, or the session's own."""
    if isinstance(calibration, Calibration):
        return calibration
    return load_calibration(session_path if calibration is None else calibration)


def _results(session_path: Path, calibration: Calibration, params: SgbmParams, verify: bool,
             n_frames: int, workers: int) -> Iterator[FrameResult]:
    """Frame results in frame order, computed in ``workers`` processes (1: in this process)."""
    init_args = (str(session_path), calibration.to_yaml_text(), dataclasses.asdict(params),
                 verify)
    if workers <= 1:
        _init_worker(*init_args, threads=cv2.getNumThreads())
        try:
            yield from map(_process_frame, range(n_frames))
        finally:
            _worker.pop("reader").close()
        return
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_worker, initargs=(*init_args, 1, True))
    try:
        yield from pool.map(_process_frame, range(n_frames), chunksize=2)
    finally:  # on Ctrl-C or an error, drop the frames not started yet
        pool.shutdown(wait=True, cancel_futures=True)


def reconstruct_session(session_path: str | Path,
                        calibration: Calibration | str | Path | None = None,
                        out_path: str | Path | None = None, workers: int | None = None,
                        progress: Callable[[int], object] | None = None,
                        sgbm_params: SgbmParams | None = None, verify: bool = True) -> Path:
    """Reconstruct all frames of a session into ``<session>.clouds.h5`` (or ``out_path``).

    ``calibration`` is a :class:`Calibration`, a YAML/session path, or ``None`` for the one
    stored in the session. ``workers`` processes (default: one per CPU core, at most the
    number of frames) share the frames; ``progress(n)`` is called with each finished frame
    count. The sidecar is written to a temporary name and renamed when complete, so an
    interrupted run leaves no partial file. A session still being recorded is reconstructed up
    to its frames flushed at the start; the sidecar then has ``session_partial = True``.
    """
    session_path = Path(session_path)
    calibration = resolve_calibration(session_path, calibration)
    params = sgbm_params or SgbmParams()
    out_path = Path(out_path) if out_path is not None else sidecar_path(session_path)
    with SessionReader(session_path) as reader:
        n_frames = reader.n_frames
        partial = reader.growing
        size = reader.frame_size
        times = reader.frame_times_ns() if n_frames else np.zeros(0, np.int64)
        fingerprint = fingerprint_of(reader)
    if tuple(size) != tuple(calibration.image_size):
        raise ReconError(f"session {session_path} has {size[0]}x{size[1]} images but the "
                         f"calibration is for {calibration.image_size[0]}x"
                         f"{calibration.image_size[1]}; use the calibration of this camera mode")
    workers = max(1, min(workers or os.cpu_count() or 1, n_frames))
    tmp_path = out_path.with_name(out_path.name + ".partial")
    writer = CloudWriter(tmp_path, {
        "session_path": str(session_path.resolve()), "session_fingerprint": fingerprint,
        "verify": verify, "session_partial": partial,
        "sgbm_json": json.dumps(dataclasses.asdict(params)),
        "software_version": __version__}, calibration.to_yaml_text())
    try:
        for i, points, colors, valid_fraction, stats, counts in _results(
                session_path, calibration, params, verify, n_frames, workers):
            writer.append(i, int(times[i]), points, colors, valid_fraction, stats, counts)
            if progress is not None:
                progress(1)
        writer.finish()
    except BaseException:
        writer.abort()
        tmp_path.unlink(missing_ok=True)
        raise
    os.replace(tmp_path, out_path)
    return out_path
