"""Live outputs for other programs: each estimate (and the trocar's force) on an LSL outlet,
or as one JSON datagram per estimate over UDP. Both are listeners of the acquisition (the
trocar's samples, the rig's opening and closing) and of the live run's estimates
(:meth:`on_estimate`, called by its estimator thread); neither blocks."""

from __future__ import annotations

import json
import math
import socket
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from vbfe.acquire import Listener
from vbfe.common.errors import LiveError
from vbfe.drivers import ForceSample
from vbfe.drivers.streams.lsl import pylsl

if TYPE_CHECKING:
    from vbfe.acquire import Acquisition
    from vbfe.live.estimator import LiveEstimate

ESTIMATE_STREAM = "vbfe-estimate"
TROCAR_STREAM = "vbfe-trocar"


class EstimateOutput(Listener):
    """A listener of the acquisition that also receives every estimate and cloud (from the
    estimator's threads: it must not block)."""

    lossy = True  # the newest frames, on the acquisition's live thread (never the file's)

    def on_estimate(self, estimate: LiveEstimate) -> None:
        """One new estimate."""

    def on_cloud(self, t_host_ns: int, points: np.ndarray, colors: np.ndarray) -> None:
        """The cloud of the frame captured at ``t_host_ns`` (points N×3 in metres, rectified
        left camera; colours N×3 RGB), from the estimator's reconstruct thread."""


def target_channels(target: str) -> list[str]:
    """Channel names of an estimate's force values for a model target."""
    if target == "magnitude":
        return ["force_magnitude"]
    if target == "xyz":
        return ["force_x", "force_y", "force_z"]
    return [f"force_{target.replace('-', 'minus_')}"]


def _outlet(
    name: str, stream_type: str, channels: Sequence[tuple[str, str]], rate_hz: float, source_id: str
) -> Any:
    lsl = pylsl()
    info = lsl.StreamInfo(name, stream_type, len(channels), rate_hz, lsl.cf_double64, source_id)
    desc = info.desc()
    desc.append_child_value("manufacturer", "vbfe")
    chans = desc.append_child("channels")
    for label, unit in channels:
        channel = chans.append_child("channel")
        channel.append_child_value("label", label)
        channel.append_child_value("unit", unit)
    return lsl.StreamOutlet(info, chunk_size=1)


class LslOutput(EstimateOutput):
    """Two LSL outlets while the rig runs: ``vbfe-estimate`` (type ``Force``, irregular: the
    force values, their prediction interval (``<channel>_lo``, ``<channel>_hi``; NaN when the
    model has none), ``ood`` (1 when the frame is outside the training data, else 0), the
    source frame's capture time ``t_frame_s`` and ``latency_s``, stamped
    with the frame's capture time on the host clock) and ``vbfe-trocar`` (type ``Force``, the
    trocar's x, y, z in newtons at its rate, each sample stamped with its host time); their
    source ids are ``<source_id>-estimate`` and ``<source_id>-trocar``."""

    def __init__(self, target: str, source_id: str = f"vbfe@{socket.gethostname()}") -> None:
        self.target, self.source_id = target, source_id
        self.estimate: Any = None
        self.trocar: Any = None

    def on_start(self, acquisition: Acquisition) -> None:
        names = target_channels(self.target)
        self.estimate = _outlet(
            ESTIMATE_STREAM,
            "Force",
            [(n, "N") for n in names]
            + [(f"{n}_{b}", "N") for b in ("lo", "hi") for n in names]
            + [("ood", ""), ("t_frame_s", "s"), ("latency_s", "s")],
            pylsl().IRREGULAR_RATE,
            f"{self.source_id}-estimate",
        )
        self.trocar = _outlet(
            TROCAR_STREAM,
            "Force",
            [("force_x", "N"), ("force_y", "N"), ("force_z", "N")],
            float(acquisition.rig.trocar.rate_hz or 0.0),
            f"{self.source_id}-trocar",
        )

    def on_estimate(self, estimate: LiveEstimate) -> None:
        """Publish one estimate (time stamp: its frame's capture time)."""
        t_frame_s = estimate.t_frame_host_ns / 1e9
        self.estimate.push_sample(
            [
                *estimate.force_n.tolist(),
                *estimate.lo_n.tolist(),
                *estimate.hi_n.tolist(),
                float(estimate.ood),
                t_frame_s,
                estimate.latency_s,
            ],
            t_frame_s,
        )

    def on_samples(self, samples: Sequence[ForceSample]) -> None:
        """Publish trocar samples (each stamped with its host time)."""
        if samples:
            self.trocar.push_chunk(
                np.array([s.force_n for s in samples], np.float64),
                [s.t_host_ns / 1e9 for s in samples],
            )

    def on_stop(self, acquisition: Acquisition) -> None:
        """Withdraw both outlets."""
        self.estimate = self.trocar = None


def udp_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6addr]:PORT`` for IPv6) as a checked ``(host, port)``."""
    host, sep, port = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise LiveError(f"--udp {text!r} is not HOST:PORT (e.g. 127.0.0.1:9870)")
    return host, int(port)


def _json_values(values: np.ndarray) -> list[float | None]:
    """Numbers for JSON, ``None`` for NaN."""
    return [None if math.isnan(v) else v for v in values.tolist()]


class UdpOutput(EstimateOutput):
    """One JSON datagram per estimate to ``host:port``::

        {"frame_seq": 12, "t_frame_host_ns": ..., "t_ready_host_ns": ..., "latency_s": 0.041,
         "target": "magnitude", "force_n": [1.52], "lo_n": [1.31], "hi_n": [1.73],
         "ood": false}

    (``force_n`` entries are ``null`` when the frame gave no estimate, ``lo_n``/``hi_n`` (the
    prediction interval) when it gave none or the model has no interval; ``ood``: the frame
    is outside the model's training data). Host times are this machine's monotonic clock
    (LSL's ``local_clock()``)."""

    def __init__(self, address: tuple[str, int], target: str) -> None:
        self.target = target
        try:
            family, kind, proto, _, sockaddr = socket.getaddrinfo(*address, type=socket.SOCK_DGRAM)[
                0
            ]
        except socket.gaierror as exc:
            raise LiveError(
                f"--udp {address[0]}:{address[1]}: cannot resolve the host ({exc.strerror})"
            ) from None
        self._sock = socket.socket(family, kind, proto)
        self._to = sockaddr

    def on_estimate(self, estimate: LiveEstimate) -> None:
        """Send one estimate (a full socket buffer or an unreachable port drops it)."""
        message = {
            "frame_seq": estimate.frame_seq,
            "t_frame_host_ns": estimate.t_frame_host_ns,
            "t_ready_host_ns": estimate.t_ready_host_ns,
            "latency_s": estimate.latency_s,
            "target": self.target,
            "force_n": _json_values(estimate.force_n),
            "lo_n": _json_values(estimate.lo_n),
            "hi_n": _json_values(estimate.hi_n),
            "ood": estimate.ood,
        }
        try:
            self._sock.sendto(json.dumps(message).encode(), self._to)
        except OSError:
            pass  # nobody listening yet (ICMP port unreachable) or buffer full: a lost datagram

    def on_stop(self, acquisition: Acquisition) -> None:
        """Close the socket."""
        self._sock.close()
