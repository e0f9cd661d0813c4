"""Reconstruct every frame of a recorded session, or a set of image pairs, into a point-cloud
file, in parallel."""

from __future__ import annotations

import dataclasses
import json
import logging
import multiprocessing
import os
import signal
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vbfe.acquire import SessionError, SessionReader
from vbfe.acquire.image_size import size_mismatch
from vbfe.calib.calibration import Calibration, load_calibration, stored_calibration
from vbfe.common.errors import ReconError
from vbfe.common.files import commit, partial_path
from vbfe.common.signals import die_with_parent, stop_pool_on_signals
from vbfe.common.version import __version__
from vbfe.recon.clouds import COUNT_COLUMNS, CloudWriter, sidecar_path
from vbfe.recon.freshness import fingerprint_of
from vbfe.recon.inputs import ImagePairs
from vbfe.recon.maps import MapOutput, write_maps
from vbfe.recon.matching import SgbmParams
from vbfe.recon.quality import ReconSettings, check_disparity_range, params_for
from vbfe.recon.triangulate import FrameCloud, Reconstructor

log = logging.getLogger(__name__)

FrameResult = tuple[int, FrameCloud, dict[str, object]]
FrameHook = Callable[[str, FrameCloud], object]
StartHook = Callable[[int, bool], object]

_worker: dict[str, Any] = {}  # per-process state: the frame source and reconstructor


def _init_worker(
    source: str | ImagePairs,
    calibration: Calibration,
    params: dict,
    verify: bool,
    settings: ReconSettings,
    keep_maps: bool,
    threads: int,
    ignore_interrupt: bool = False,
) -> None:
    """Open the frame source (a session path or image pairs) and build the reconstructor once
    per worker process (child processes leave Ctrl-C to the parent, which stops the pool)."""
    if ignore_interrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        die_with_parent()
    cv2.setNumThreads(threads)
    _worker["reader"] = SessionReader(source) if isinstance(source, str) else source
    _worker["keep_maps"] = keep_maps
    _worker["reconstructor"] = Reconstructor(
        calibration,
        SgbmParams(**params),
        verify=verify,
        settings=settings,
    )


def _process_frame(i: int) -> FrameResult:
    """Reconstruct frame ``i`` of the worker's source; returns the cloud (without its
    per-pixel maps unless they were asked for) and its statistics."""
    try:
        frame = _worker["reader"].frame(i)
    except (OSError, KeyError, SessionError):  # the recorder finalized the file meanwhile
        reader = _worker["reader"]
        if not isinstance(reader, SessionReader):
            raise
        reader.close()
        _worker["reader"] = SessionReader(reader.path)
        frame = _worker["reader"].frame(i)
    cloud = _worker["reconstructor"].process(frame.left, frame.right)
    d = cloud.disparity[cloud.valid]
    stats = {
        "valid_fraction": float(cloud.valid.mean()),
        "disparity_px": (
            np.array([d.min(), np.median(d), d.max(), d.mean()], np.float32)
            if d.size
            else np.full(4, np.nan, np.float32)
        ),
        "match_counts": np.array([cloud.counts.get(k, -1) for k in COUNT_COLUMNS], np.int64),
        "decoded_fraction": cloud.decoded_fraction,
        "edge_fraction": cloud.edge_fraction,
    }
    if not _worker["keep_maps"]:  # nothing per pixel crosses the process boundary
        cloud = dataclasses.replace(cloud, disparity=None, valid=None, status=None)
    return i, cloud, stats


def _results(
    source: str | ImagePairs,
    calibration: Calibration,
    params: SgbmParams,
    verify: bool,
    settings: ReconSettings,
    keep_maps: bool,
    n_frames: int,
    workers: int,
) -> Iterator[FrameResult]:
    """Frame results in frame order, computed in ``workers`` processes (1: in this process)."""
    init_args = (
        source,
        calibration,  # pickled to worker processes as it is (no YAML round trip)
        dataclasses.asdict(params),
        verify,
        settings,
        keep_maps,
    )
    if workers <= 1:
        _init_worker(*init_args, threads=cv2.getNumThreads())
        try:
            yield from map(_process_frame, range(n_frames))
        finally:
            reader = _worker.pop("reader")
            if isinstance(reader, SessionReader):
                reader.close()
        return
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
        initargs=(*init_args, 1, True),
    )
    try:
        with stop_pool_on_signals(pool):
            yield from pool.map(_process_frame, range(n_frames), chunksize=2)
    finally:  # on Ctrl-C or an error, drop the frames not started yet
        pool.shutdown(wait=True, cancel_futures=True)


def _reconstruct(
    source: str | ImagePairs,
    kind: str,
    fingerprint: str,
    n_frames: int,
    times: np.ndarray,
    names: list[str],
    calibration: Calibration,
    out_path: Path,
    workers: int | None,
    progress: Callable[[int], object] | None,
    params: SgbmParams,
    verify: bool,
    settings: ReconSettings,
    maps: MapOutput | None,
    per_frame: FrameHook | None = None,
    started: StartHook | None = None,
    partial: bool = False,
) -> Path:
    """Reconstruct ``n_frames`` frames of ``source`` into ``out_path`` (written to a temporary
    name and renamed when complete, so an interrupted run leaves no partial file); ``partial``
    marks the clouds of a session that was still being recorded; ``started(n_frames,
    partial)`` is called once the settings are checked, ``per_frame(name, cloud)`` with each
    frame's cloud and its per-pixel maps."""
    params = params_for(calibration, params, settings)
    check_disparity_range(params, calibration.image_size)
    if started is not None:
        started(n_frames, partial)
    workers = max(1, min(workers or os.cpu_count() or 1, n_frames))
    tmp_path = partial_path(out_path)
    writer = CloudWriter(
        tmp_path,
        {
            "session_path": str(
                Path(source if isinstance(source, str) else source.lefts[0]).resolve()
            ),
            "session_fingerprint": fingerprint,
            "source_kind": kind,
            "verify": verify,
            "session_partial": partial,
            "sgbm_json": json.dumps(dataclasses.asdict(params)),
            "software_version": __version__,
        },
        calibration.to_yaml_text(),
    )
    try:
        keep_maps = maps is not None or per_frame is not None
        for i, cloud, stats in _results(
            source, calibration, params, verify, settings, keep_maps, n_frames, workers
        ):
            writer.append(i, int(times[i]), cloud.points, cloud.colors, stats, cloud.verified)
            if maps is not None:
                write_maps(
                    maps.folder, names[i], cloud.disparity, calibration, maps.fmt, cloud.status
                )
            if per_frame is not None:
                per_frame(names[i], cloud)
            if progress is not None:
                progress(1)
        writer.finish()
        log.info(
            "%d %s frames reconstructed into %s (%d workers)", n_frames, kind, out_path, workers
        )
    except BaseException:
        writer.abort()
        tmp_path.unlink(missing_ok=True)
        raise
    return commit(tmp_path, out_path)


def _check_size(what: str, size: tuple[int, int], calibration: Calibration) -> None:
    mismatch = size_mismatch(f"{what} has", size, "the calibration", calibration.image_size)
    if mismatch:
        raise ReconError(mismatch)


def reconstruct_images(
    pairs: ImagePairs,
    calibration: Calibration,
    out_path: str | Path | None = None,
    workers: int | None = 1,
    progress: Callable[[int], object] | None = None,
    sgbm_params: SgbmParams | None = None,
    verify: bool = True,
    settings: ReconSettings | None = None,
    maps: MapOutput | None = None,
    per_frame: FrameHook | None = None,
    started: StartHook | None = None,
) -> Path:
    """Reconstruct image pairs (see :mod:`vbfe.recon.inputs`) into a cloud file, by default
    ``<first left image>.clouds.h5``; frame times are 0. ``per_frame(name, cloud)`` sees each
    pair's cloud with its per-pixel maps (e.g. to score it against ground truth);
    ``started(n_pairs, False)`` is called once the settings are checked."""
    _check_size(f"{pairs.lefts[0]}", pairs.frame_size(), calibration)
    out_path = Path(out_path) if out_path is not None else sidecar_path(pairs.lefts[0])
    return _reconstruct(
        pairs,
        "images",
        pairs.fingerprint(),
        pairs.n_frames,
        np.zeros(pairs.n_frames, np.int64),
        list(pairs.names),
        calibration,
        out_path,
        workers,
        progress,
        sgbm_params or SgbmParams(),
        verify,
        settings or ReconSettings(),
        maps,
        per_frame,
        started,
    )


def reconstruct_session(
    session_path: str | Path,
    calibration: Calibration | str | Path | None = None,
    out_path: str | Path | None = None,
    workers: int | None = None,
    progress: Callable[[int], object] | None = None,
    sgbm_params: SgbmParams | None = None,
    verify: bool = True,
    settings: ReconSettings | None = None,
    maps: MapOutput | None = None,
    started: StartHook | None = None,
) -> Path:
    """Reconstruct all frames of a session into ``<session>.clouds.h5`` (or ``out_path``).

    ``calibration`` is a :class:`Calibration`, a YAML path, or ``None`` for the one stored in
    the session. ``workers`` processes (default: one per CPU core, at most the number of
    frames) share the frames; ``started(n_frames, partial)`` is called once the session is
    read and the settings checked, ``progress(n)`` with each finished frame count. ``settings`` (the
    ``[recon]`` table) give the depth range a zero ``num_disparities`` is derived from; ``maps``
    asks for disparity/depth/quality maps too. The sidecar is written to a temporary name and
    renamed when complete, so an interrupted run leaves no partial file. A session still being
    recorded is reconstructed up to its frames flushed at the start (``partial``); the sidecar
    then has ``session_partial = True``.
    """
    session_path = Path(session_path)
    out_path = Path(out_path) if out_path is not None else sidecar_path(session_path)
    with SessionReader(session_path) as reader:  # the one look before the workers open it
        n_frames = reader.n_frames
        partial = reader.growing
        size = reader.frame_size
        times = reader.frame_times_ns() if n_frames else np.zeros(0, np.int64)
        fingerprint = fingerprint_of(reader)
        if calibration is None:
            calibration = stored_calibration(reader.calibration_yaml(), session_path)
    if not isinstance(calibration, Calibration):
        calibration = load_calibration(calibration)
    _check_size(f"session {session_path}", size, calibration)
    names = [f"frame_{i:06d}" for i in range(n_frames)]
    return _reconstruct(
        str(session_path),
        "session",
        fingerprint,
        n_frames,
        times,
        names,
        calibration,
        out_path,
        workers,
        progress,
        sgbm_params or SgbmParams(),
        verify,
        settings or ReconSettings(),
        maps,
        started=started,
        partial=partial,
    )
