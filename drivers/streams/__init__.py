"""Extra streams of the rig: other programs' and devices' Lab Streaming Layer (LSL) streams,
recorded beside the camera and the trocar on the host clock (docs/streams.md)."""

from vbfe.drivers.streams.chunk import StreamChunk, StreamInfo
from vbfe.drivers.streams.settings import StreamSpec, stream_specs

__all__ = ["StreamChunk", "StreamInfo", "StreamSpec", "stream_specs"]
