"""A read-only client of the Foxglove WebSocket protocol, as the Foxglove app speaks it:
RFC 6455 over a plain socket (no further library), subprotocol ``foxglove.sdk.v1``; the
server's JSON ``advertise`` operations, ``subscribe``, and binary message-data frames
(opcode 1: subscription id u32, log time u64, payload; little-endian)."""

from __future__ import annotations

import base64
import contextlib
import json
import os
import socket
import struct
import time
from collections.abc import Iterator
from typing import Any

SUBPROTOCOLS = "foxglove.sdk.v1, foxglove.websocket.v1"
_TEXT, _BINARY, _CLOSE, _PING, _PONG = 1, 2, 8, 9, 10
_MESSAGE_DATA = 1
_SETTLE_S = 0.3


class FoxgloveClient:
    """Connect to ``ws://host:port`` (retrying for ``timeout_s`` while it starts), offering
    ``subprotocols``; :attr:`subprotocol` is the one the server chose.

    :raises ConnectionError: when the server refuses the upgrade (its answer in the message).
    """

    def __init__(
        self, host: str, port: int, timeout_s: float = 30.0, subprotocols: str = SUBPROTOCOLS
    ) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self._sock = socket.create_connection((host, port), timeout=timeout_s)
                break
            except ConnectionRefusedError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        key = base64.b64encode(os.urandom(16)).decode()
        self._sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {subprotocols}\r\n\r\n"
            ).encode()
        )
        self._buffer = b""
        while b"\r\n\r\n" not in self._buffer:
            self._buffer += self._recv_some()
        head, self._buffer = self._buffer.split(b"\r\n\r\n", 1)
        status = head.split(b"\r\n", 1)[0]
        if b" 101 " not in status:
            self._sock.settimeout(1.0)
            with contextlib.suppress(OSError):  # the body, when the server says why
                self._buffer += self._sock.recv(1 << 16)
            self._sock.close()
            answer = (head + b"\r\n\r\n" + self._buffer).decode(errors="replace")
            raise ConnectionError(f"not a WebSocket upgrade: {answer}")
        self.subprotocol = next(
            (
                line.split(b":", 1)[1].strip().decode()
                for line in head.split(b"\r\n")
                if line.lower().startswith(b"sec-websocket-protocol:")
            ),
            "",
        )
        self.channels: dict[int, dict[str, Any]] = {}  # advertised, by channel id
        self.server_info: dict[str, Any] = {}
        self.statuses: list[dict[str, Any]] = []  # the server's status messages, as read
        host, port = self._sock.getsockname()[:2]
        self.address = f"{host}:{port}"  # as the server sees this client
        self._subscriptions: dict[int, int] = {}  # subscription id -> channel id
        self.closed = False  # the server closed the connection

    def close(self) -> None:
        """Say goodbye (a WebSocket close frame, status 1000) and close the socket."""
        try:
            self._send(_CLOSE, struct.pack("!H", 1000))
        except OSError:
            pass  # the server is gone already
        self._sock.close()

    def __enter__(self) -> FoxgloveClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _recv_some(self) -> bytes:
        data = self._sock.recv(1 << 16)
        if not data:
            raise ConnectionError("the server closed the connection")
        return data

    def _exact(self, n: int) -> bytes:
        while len(self._buffer) < n:
            self._buffer += self._recv_some()
        out, self._buffer = self._buffer[:n], self._buffer[n:]
        return out

    def _send(self, opcode: int, payload: bytes) -> None:
        mask = os.urandom(4)
        n = len(payload)
        size = (
            struct.pack("!B", 0x80 | n)
            if n < 126
            else struct.pack("!BH", 0x80 | 126, n)
            if n < 1 << 16
            else struct.pack("!BQ", 0x80 | 127, n)
        )
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self._sock.sendall(struct.pack("!B", 0x80 | opcode) + size + mask + masked)

    def _frame(self) -> tuple[int, bytes]:
        """One whole message (continuations joined); pings answered."""
        opcode, parts = None, []
        while True:
            first, second = self._exact(2)
            n = second & 0x7F
            if n == 126:
                n = struct.unpack("!H", self._exact(2))[0]
            elif n == 127:
                n = struct.unpack("!Q", self._exact(8))[0]
            mask = self._exact(4) if second & 0x80 else None
            payload = self._exact(n)
            if mask is not None:
                payload = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
            code = first & 0x0F
            if code == _PING:
                self._send(_PONG, payload)
                continue
            if code == _CLOSE:
                raise ConnectionError("the server closed the WebSocket")
            opcode = code if code else opcode
            parts.append(payload)
            if first & 0x80:
                return int(opcode or 0), b"".join(parts)

    def _handle_text(self, payload: bytes) -> None:
        message = json.loads(payload)
        if message.get("op") == "advertise":
            for channel in message["channels"]:
                self.channels[channel["id"]] = channel
        elif message.get("op") == "unadvertise":
            for channel_id in message["channelIds"]:
                self.channels.pop(channel_id, None)
        elif message.get("op") == "serverInfo":
            self.server_info = message
        elif message.get("op") == "status":
            self.statuses.append(message)

    def wait_for_topics(self, topics: set[str], timeout_s: float = 30.0) -> dict[str, dict]:
        """The advertised channels of ``topics`` (by topic), once all are advertised."""
        deadline = time.monotonic() + timeout_s
        while True:
            by_topic = {c["topic"]: c for c in self.channels.values()}
            if topics <= by_topic.keys():
                # foxglove-sdk advertises a channel a moment before it takes subscriptions
                # to it (a subscription at once is refused as an "unknown channel")
                for _ in self.messages(_SETTLE_S):
                    pass
                return {c["topic"]: c for c in self.channels.values()}
            if time.monotonic() > deadline:
                raise TimeoutError(f"never advertised: {sorted(topics - by_topic.keys())}")
            opcode, payload = self._frame()
            if opcode == _TEXT:
                self._handle_text(payload)

    def subscribe(self, channel_ids: list[int]) -> None:
        """Ask for the messages of these channels."""
        subscriptions = []
        for channel_id in channel_ids:
            sub_id = len(self._subscriptions) + 1
            self._subscriptions[sub_id] = channel_id
            subscriptions.append({"id": sub_id, "channelId": channel_id})
        self._send(_TEXT, json.dumps({"op": "subscribe", "subscriptions": subscriptions}).encode())

    def messages(self, timeout_s: float) -> Iterator[tuple[dict[str, Any], int, bytes]]:
        """(advertised channel, log time ns, payload) of each message received, for
        ``timeout_s`` or until the server closes the connection (then ``closed``)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self.closed:
            self._sock.settimeout(max(0.05, deadline - time.monotonic()))
            try:
                opcode, payload = self._frame()
            except TimeoutError:
                return
            except ConnectionError:
                self.closed = True
                return
            if opcode == _TEXT:
                self._handle_text(payload)
            elif opcode == _BINARY and payload[0] == _MESSAGE_DATA:
                sub_id, log_time = struct.unpack_from("<IQ", payload, 1)
                channel = self.channels.get(self._subscriptions.get(sub_id, -1))
                if channel is not None:
                    yield channel, log_time, payload[13:]


def app_schema_error(channel: dict[str, Any]) -> str | None:
    """What the Foxglove app says when it cannot read an advertised JSON channel's schema
    (None: it reads it), by the rules of its ``parseChannel`` and ``parseJsonSchema``
    (lichtblick-suite/lichtblick 66adecb, packages/mcap-support/src): JSON messages need a
    ``jsonschema`` schema (or none) whose root is an object; each property is a ``oneOf`` of
    numeric ``const`` alternatives, or one ``type`` of boolean, string (no encoding but base64),
    number, integer, a nested object (same rules), or an array whose ``items`` are one of those
    (strings without an encoding); anything else, a list of types or ``"null"`` included, is
    refused."""
    if channel["encoding"] != "json":
        return None
    if channel["schemaEncoding"] != "jsonschema":
        return f"JSON with schema encoding {channel['schemaEncoding']!r}"
    if not channel["schema"]:
        return None
    schema = json.loads(channel["schema"])
    if not isinstance(schema, dict):
        return "schema is not a JSON object"
    return _object_error(schema, channel["schemaName"])


def _object_error(schema: dict[str, Any], path: str) -> str | None:
    if schema.get("type") != "object":
        return f'Expected "type": "object" for schema {path}, got {schema.get("type")!r}'
    for name, field in (schema.get("properties") or {}).items():
        where = f"{path}.{name}"
        if isinstance(field.get("oneOf"), list):
            if not all(isinstance(alt.get("const"), int | float) for alt in field["oneOf"]):
                return f"Unsupported type for {where}: oneOf alternatives must be numbers"
            continue
        kind = field.get("type")
        if kind in ("boolean", "number", "integer"):
            continue
        if kind == "string":
            if field.get("contentEncoding") not in (None, "base64"):
                return f"Unsupported contentEncoding {field['contentEncoding']!r} in {where}"
        elif kind == "object":
            error = _object_error(field, where)
            if error:
                return error
        elif kind == "array":
            items = field.get("items") or {}
            item_kind = items.get("type")
            if item_kind == "string" and items.get("contentEncoding") is not None:
                return f"Unsupported contentEncoding for array item {where}"
            if item_kind == "object":
                error = _object_error(items, where)
                if error:
                    return error
            elif item_kind not in ("boolean", "string", "number", "integer"):
                return f"Unsupported type {json.dumps(item_kind)} for array item {where}"
        else:
            return f"Unsupported type {json.dumps(kind)} for {where}"
    return None
