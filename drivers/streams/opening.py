"""Build the ``[streams]`` of a rig config and open them together (resolving in parallel)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any

from vbfe.drivers.errors import DeviceError
from vbfe.drivers.streams.lsl import LslStream
from vbfe.drivers.streams.settings import stream_specs


def streams_from_config(config: dict[str, dict[str, Any]]) -> list[LslStream]:
    """The extra streams a rig config names (built, not opened; ConfigError when the table is
    wrong)."""
    return [LslStream(spec) for spec in stream_specs(config)]


def open_streams(streams: list[LslStream]) -> tuple[list[LslStream], list[str]]:
    """Open ``streams`` at once (each resolve waits up to its own timeout). Returns the opened
    streams and one warning per optional stream that was not found; a required one missing
    raises DeviceError naming it, after closing the others."""
    if not streams:
        return [], []
    with ThreadPoolExecutor(max_workers=len(streams)) as pool:
        failures = list(pool.map(_try_open, streams))
    opened = [s for s, failure in zip(streams, failures) if failure is None]
    required = [f for s, f in zip(streams, failures) if f is not None and s.spec.required]
    if required:
        for stream in opened:
            stream.close()
        raise DeviceError(required[0] if len(required) == 1 else
                          f"{len(required)} required streams are missing: "
                          + "; ".join(required))
    warnings = [f"optional {f} (recording without it)" for f in failures if f is not None]
    return opened, warnings


def _try_open(stream: LslStream) -> str | None:
    try:
        stream.open()
    except DeviceError as exc:
        return str(exc)
    return None
