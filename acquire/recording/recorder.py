"""The recorder: an acquisition whose first listener writes it into one session file."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from vbfe.acquire.recording.acquisition import Acquisition, AcquisitionStats, PatternSource
from vbfe.acquire.recording.listener import Listener
from vbfe.acquire.recording.session_sink import SessionSink
from vbfe.acquire.session.layout import DEFAULT_COMPRESSION, StreamSpec
from vbfe.drivers.projector.pattern import PATTERN_NAME
from vbfe.drivers.rig import Rig


class Recorder(Acquisition):
    """Record a rig into the session ``path`` (see :class:`SessionSink` for the file's
    options; ``streams`` the specs of extra streams), handing every record to ``listeners``
    too.

    Use as ``with Recorder(rig, path) as rec: rec.run(duration_s)`` or call :meth:`start` /
    :meth:`stop` yourself; the rig is opened at the start and closed at the stop.
    """

    def __init__(
        self,
        rig: Rig,
        path: str | Path,
        compression: str = DEFAULT_COMPRESSION,
        flush_interval_s: float = 1.0,
        metadata: dict[str, Any] | None = None,
        calibration_yaml: str | None = None,
        queue_size: int = 256,
        queue_bytes: int = 0,
        min_free_bytes: int = 1 << 30,
        pattern: PatternSource | None = None,
        pattern_name: str = PATTERN_NAME,
        on_flush: Callable[[AcquisitionStats], None] | None = None,
        overwrite: bool = False,
        listeners: tuple[Listener, ...] = (),
        streams: tuple[StreamSpec, ...] = (),
    ) -> None:
        self.sink = SessionSink(
            path,
            compression,
            flush_interval_s,
            metadata,
            calibration_yaml,
            min_free_bytes,
            overwrite,
            on_flush,
            streams,
        )
        super().__init__(
            rig, pattern, pattern_name, queue_size, (self.sink, *listeners), queue_bytes=queue_bytes
        )
        self.what = str(self.sink.path)

    def start(self, duration_s: float | None = None) -> None:
        """Start as :meth:`Acquisition.start` does, the session collecting the log lines from
        the opening of the devices on (``vbfe.*`` loggers, information and above)."""
        self.sink.log.attach()
        try:
            super().start(duration_s)
        except BaseException:
            self.sink.log.detach()
            raise

    @property
    def path(self) -> Path:
        """The session file."""
        return self.sink.path

    @property
    def metadata(self) -> dict[str, Any]:
        """The session metadata (add to it before :meth:`start`)."""
        return self.sink.metadata
