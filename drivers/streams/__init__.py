"""Extra streams of the rig: other programs' and devices' Lab Streaming Layer (LSL) streams,
recorded beside the camera and the trocar on the host clock (docs/how-to/publish-streams.md)."""

from vbfe.drivers.streams.records import StreamInfo, StreamSample
from vbfe.drivers.streams.settings import StreamSource, stream_sources

__all__ = ["StreamInfo", "StreamSample", "StreamSource", "stream_sources"]
