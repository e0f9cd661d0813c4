"""Live outputs (LSL outlet, UDP datagrams) and the remote-control protocol, on loopback."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pylsl
import pytest

from vbfe.acquire.recording.remote import (
    Command,
    RemoteControl,
    RemoteSessions,
    parse_command,
    send_command,
    session_path,
)
from vbfe.common.errors import LiveError, SessionError
from vbfe.drivers.samples import ForceSample
from vbfe.live.estimator import LiveEstimate
from vbfe.live.outputs import LslOutput, UdpOutput, udp_address


def _estimate(
    seq: int, force: list[float], latency_s: float = 0.04, half_width: float | None = 0.25
) -> LiveEstimate:
    t_frame = time.monotonic_ns() - int(latency_s * 1e9)
    bounds = (
        {"lo_n": np.array(force) - half_width, "hi_n": np.array(force) + half_width}
        if half_width is not None
        else {}
    )
    return LiveEstimate(
        force_n=np.array(force),
        frame_seq=seq,
        t_frame_host_ns=t_frame,
        t_ready_host_ns=t_frame + int(latency_s * 1e9),
        stage_s=(0.0, 0.03, 0.01),
        n_points=1000,
        ood=seq % 2 == 1,
        **bounds,
    )


def test_lsl_output_publishes_estimates_and_trocar() -> None:
    source = f"vbfe-test-{time.monotonic_ns()}"
    output = LslOutput("xyz", source_id=source)
    output.on_start(SimpleNamespace(rig=SimpleNamespace(trocar=SimpleNamespace(rate_hz=1000.0))))
    inlets = {}
    for name in ("vbfe-estimate", "vbfe-trocar"):
        found = pylsl.resolve_bypred(
            f"name='{name}' and source_id='{source}-{name[5:]}'", timeout=5.0
        )
        inlets[name] = pylsl.StreamInlet(found[0])
        inlets[name].open_stream(timeout=5.0)
    info = inlets["vbfe-estimate"].info(timeout=5.0)
    channel, labels = info.desc().child("channels").child("channel"), []
    while not channel.empty():
        labels.append((channel.child_value("label"), channel.child_value("unit")))
        channel = channel.next_sibling()
    assert labels == [
        ("force_x", "N"),
        ("force_y", "N"),
        ("force_z", "N"),
        ("force_x_lo", "N"),
        ("force_y_lo", "N"),
        ("force_z_lo", "N"),
        ("force_x_hi", "N"),
        ("force_y_hi", "N"),
        ("force_z_hi", "N"),
        ("ood", ""),
        ("t_frame_s", "s"),
        ("latency_s", "s"),
    ]
    estimate = _estimate(7, [0.5, -1.0, 2.0])
    output.on_estimate(estimate)
    now = time.monotonic_ns()
    output.on_samples(
        [ForceSample(np.array([0.1, 0.2, 0.3]), k, 0, now + k * 1_000_000) for k in range(5)]
    )
    sample, stamp = inlets["vbfe-estimate"].pull_sample(timeout=5.0)
    assert sample[:3] == [0.5, -1.0, 2.0] and sample[11] == pytest.approx(0.04)
    assert sample[3:9] == [0.25, -1.25, 1.75, 0.75, -0.75, 2.25]  # the interval
    assert sample[9] == 1.0  # frame 7 is flagged outside the training data
    assert stamp == pytest.approx(estimate.t_frame_host_ns / 1e9, abs=1e-6) == sample[10]
    values, stamps = inlets["vbfe-trocar"].pull_chunk(timeout=5.0, max_samples=5, min_samples=5)
    assert len(values) == 5 and values[0] == pytest.approx([0.1, 0.2, 0.3])
    assert stamps[4] - stamps[0] == pytest.approx(0.004, abs=1e-6)
    assert inlets["vbfe-trocar"].info().nominal_srate() == 1000.0
    output.on_stop(None)


def test_udp_output_sends_one_json_datagram_per_estimate() -> None:
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(5.0)
    output = UdpOutput(udp_address(f"127.0.0.1:{receiver.getsockname()[1]}"), "magnitude")
    output.on_estimate(_estimate(3, [1.25]))
    output.on_estimate(_estimate(4, [float("nan")], half_width=None))
    first, second = (json.loads(receiver.recv(65536)) for _ in range(2))
    assert first["frame_seq"] == 3 and first["force_n"] == [1.25]
    assert first["lo_n"] == [1.0] and first["hi_n"] == [1.5] and first["ood"] is True
    assert first["t_ready_host_ns"] - first["t_frame_host_ns"] == pytest.approx(4e7, abs=2)
    assert second["force_n"] == [None] and second["target"] == "magnitude"
    # a model without an interval: null bounds; frame 4 is inside the training data
    assert second["lo_n"] == second["hi_n"] == [None] and second["ood"] is False
    output.on_stop(None)
    receiver.close()
    for bad in ("localhost", "host:0", ":9870", "h:70000", "h:x"):
        with pytest.raises(LiveError, match="is not HOST:PORT"):
            udp_address(bad)
    assert udp_address("[::1]:9870") == ("::1", 9870)


def test_commands_parse_as_labrecorder_sends_them() -> None:
    assert parse_command("start\n") == Command("start")
    assert parse_command("select all") == Command("select", "all")
    # the example of LabRecorder's README (Remote Control), byte for byte
    line = (
        b"filename {root:C:\\Data\\} {template:exp%n\\%p_block_%b.xdf} {run:2} "
        b"{participant:P003} {task:MemoryGuided}\n"
    ).decode()
    command = parse_command(line)
    assert command.options == {
        "root": "C:\\Data\\",
        "template": "exp%n\\%p_block_%b.xdf",
        "run": "2",
        "participant": "P003",
        "task": "MemoryGuided",
    }
    assert session_path(
        {**command.options, "root": "/data/study", "template": "exp%n/%p_block_%b.xdf"}
    ) == Path("/data/study/exp002/P003_block_MemoryGuided.h5")
    assert session_path(
        {
            "root": "/d",
            "template": "sub-%p/ses-%s/%m_run-%r.xdf",
            "participant": "7",
            "session": "1",
            "modality": "beh",
        }
    ) == Path("/d/sub-7/ses-1/beh_run-001.h5")
    assert parse_command("mark  grasp  begins ") == Command("mark", "grasp  begins")
    for bad in (
        "begin",
        "filename",
        "filename {color:red}",
        "filename {run:two}",
        "mark",
        "start now",
    ):
        with pytest.raises(SessionError):
            parse_command(bad)


class _Recording:
    def __init__(self, path: Path) -> None:
        self.path, self.marks = path, []
        path.write_bytes(b"")

    def mark(self, text: str, t_host_ns: int) -> None:
        self.marks.append((t_host_ns, text))

    def stop(self, reason: str = "stopped by remote control") -> str:
        return f"{self.path}: {reason}"


def test_remote_control_server_answers_like_labrecorder(tmp_path: Path) -> None:
    started: list[_Recording] = []
    sessions = RemoteSessions(
        lambda p: started.append(_Recording(p)) or started[-1], on_message=lambda m: None
    )
    server = RemoteControl(sessions, port=0)
    try:
        with socket.create_connection(("127.0.0.1", server.port), timeout=5.0) as sock:

            def say(line: str) -> str:
                sock.sendall(line.encode() + b"\n")
                return sock.recv(4096).decode()

            assert say("start").startswith("ERROR start: send filename")
            assert say("select all") == "OK"
            assert (
                say(f"filename {{root:{tmp_path}}} {{template:%p/run%n.xdf}} {{participant:P1}}")
                == "OK"
            )
            assert say("start") == "OK" and sessions.recording
            before = time.monotonic_ns()
            assert send_command("mark trial 1", port=server.port) == "OK"
            assert say("start").startswith("ERROR start: already recording")
            assert say("stop") == "OK" and not sessions.recording
            assert say("start").startswith("ERROR start:") and "already exists" in say("start")
            assert say("filename {run:2}") == "OK" and say("start") == "OK"
            assert say("select none").startswith("ERROR")
            assert say("bogus").startswith("ERROR unknown command")
        assert sessions.recording  # a client leaving does not stop the recording
        sessions.close()
    finally:
        server.close()
    assert [r.path for r in started] == [tmp_path / "P1/run001.h5", tmp_path / "P1/run002.h5"]
    assert sessions.finished == [r.path for r in started]
    ((t_mark, text),) = started[0].marks
    assert text == "trial 1" and before <= t_mark <= time.monotonic_ns()
    with pytest.raises(SessionError, match="no recorder answers"):
        send_command("mark x", port=server.port, timeout_s=1.0)
