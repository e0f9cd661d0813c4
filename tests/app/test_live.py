"""Live force estimation: the newest-frame mailbox, reduced-resolution reconstruction, and
`vbfe live` on the bench with a model trained here, recording its estimate stream."""

import csv
import signal
import subprocess
import sys
import threading

import numpy as np
import pytest

from vbfe.acquire import SessionReader
from vbfe.common.mailbox import Mailbox
from vbfe.drivers.sim.render import render_scene
from vbfe.drivers.sim.rig import default_rig
from vbfe.drivers.sim.tissue import TissueSurface, tissue_texture
from vbfe.estimate.dataset import DEFAULT_PROTOCOL
from vbfe.estimate.model_file import load_model
from vbfe.estimate.synthetic import synthetic_sessions
from vbfe.estimate.train_config import TrainConfig
from vbfe.estimate.training import train
from vbfe.live.estimator import STAGES
from vbfe.recon import Reconstructor, make_pattern
from vbfe.rig_config import builtin_rig, load_rig
from vbfe.truth import calibration_from_rig, true_rig


def test_mailbox_gives_the_newest_item_and_counts_the_skipped():
    box: Mailbox[int] = Mailbox()
    assert box.take(0.01) is None
    for i in range(5):
        box.put(i)
    assert box.take(0.01) == 4 and box.skipped == 4 and box.put_count == 5
    got = []
    consumer = threading.Thread(target=lambda: got.append(box.take(2.0)))
    consumer.start()
    box.put(7)
    consumer.join()
    assert got == [7] and box.skipped == 4
    box.put(10, pinned=True)  # a pinned item is never replaced, and taken first
    box.put(11)
    box.put(12)
    assert [box.take(0.01), box.take(0.01), box.take(0.01)] == [10, 12, None]
    assert box.skipped == 5


def test_half_resolution_reconstruction_sees_the_same_depth():
    rig = default_rig(640, 360)
    tissue = TissueSurface(texture=tissue_texture(np.random.default_rng(3)))
    pair = render_scene(
        rig,
        tissue,
        make_pattern(rig.projector.width, rig.projector.height),
        rng=np.random.default_rng(4),
    )
    calibration = calibration_from_rig(rig)
    half = calibration.scaled(0.5)
    assert half.image_size == (320, 180)
    assert half.f == pytest.approx(calibration.f / 2) and half.B == pytest.approx(calibration.B)
    import cv2

    full_cloud = Reconstructor(calibration).process(pair.left, pair.right)
    small = [
        cv2.resize(im, half.image_size, interpolation=cv2.INTER_AREA)
        for im in (pair.left, pair.right)
    ]
    half_cloud = Reconstructor(half).process(*small)
    assert len(half_cloud.points) > 0.15 * len(full_cloud.points)
    z_full, z_half = np.median(full_cloud.points[:, 2]), np.median(half_cloud.points[:, 2])
    assert z_half == pytest.approx(z_full, rel=0.01)
    assert z_full == pytest.approx(0.06, rel=0.1)  # the tissue lies at the working distance


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """A trained (tiny) model, the bench's calibration and a 320x180 bench rig config."""
    folder = tmp_path_factory.mktemp("live")
    model = folder / "model.pt"
    train_config = TrainConfig(
        epochs=8,
        batch_size=16,
        n_points=64,
        conv_channels=[16, 32, 64],
        head_channels=[32],
        val_fraction=1 / 3,
        seed=0,
        threads=1,
        cnn_epochs=5,
        history_frames=0,
    )
    train(synthetic_sessions(repeats=1, seed=1, fps=4, points_per_side=20), model, train_config)
    bench = {"width": 320, "height": 180, "fps": 15.0, "distortion": False, "seed": 3}
    toml = folder / "rig.toml"
    toml.write_text(
        "[bench]\n"
        + "".join(
            f"{k} = {str(v).lower() if isinstance(v, bool) else v}\n" for k, v in bench.items()
        )
    )
    config = builtin_rig({"bench": dict(bench)})
    calib = calibration_from_rig(true_rig(config)).save(folder / "calib.yaml")
    return folder, model, calib, toml


def vbfe(*args):
    return subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=240,
    )


@pytest.mark.slow  # real time, then reconstruct and evaluate its session
def test_live_on_the_bench_records_an_estimate_stream_that_evaluate_scores(rig):
    folder, model, calib, bench_toml = rig
    session = folder / "live.h5"
    # every row, the whole depth range: live reconstructs each frame as `vbfe reconstruct`
    # does, so its estimates can be compared with the offline evaluation's below
    toml = folder / "rig-full-rows.toml"
    toml.write_text(bench_toml.read_text() + "[live]\nrow_scale = 1.0\ndepth_margin_mm = 0.0\n")
    result = vbfe(
        "live",
        "--model",
        model,
        "--calib",
        calib,
        "--record",
        session,
        "--duration",
        4,
        "--headless",
        "--config",
        toml,
    )
    assert result.returncode == 0, result.stderr
    status_lines = [line for line in result.stdout.splitlines() if line.startswith("live ")]
    assert len(status_lines) >= 2 and "est/s" in status_lines[-1]
    with SessionReader(session) as reader:
        stream = reader.estimates()
        seqs_in_order = reader.stream_times("camera")[2][: reader.n_frames]
        seqs = set(seqs_in_order.tolist())
        assert reader.attrs["schema_version"] == 2
        assert reader.metadata["rig"] == f"rig file {toml} (from --config): simulated bench"
    n, seen, skipped = len(stream), stream.attrs["frames_seen"], stream.attrs["skipped_frames"]
    assert n >= 10, f"only {n} estimates in 4 s"
    # every delivered frame was estimated or skipped (the frames in flight at the stop drain)
    assert stream.attrs["estimated"] + skipped == seen
    assert n == stream.attrs["estimated"] - stream.attrs["of_unrecorded_frames"]
    assert set(stream.frame_seq.tolist()) <= seqs  # each estimate names a recorded frame
    assert np.all(np.diff(stream.frame_seq) > 0) and np.all(np.diff(stream.t_ready_host_ns) > 0)
    latency = stream.latency_s
    assert np.all(latency > 0) and np.all(latency < 2.0)
    assert stream.stages == list(STAGES) and stream.stage_s.shape == (n, len(STAGES))
    assert np.all(stream.stage_s >= 0)
    assert np.isfinite(stream.force_n).all()
    # each estimate with its prediction interval and whether its frame is outside the model's
    # training data (synthetic clouds, unlike the bench's: the flag may be up)
    assert np.all((stream.lo_n < stream.force_n) & (stream.force_n < stream.hi_n))
    assert stream.ood.dtype == bool and stream.ood.shape == (n,)
    inspect = vbfe("inspect", session)
    assert f"estimate  {n} live estimates" in inspect.stdout
    scored = vbfe("evaluate", "--live", session, "--out", folder / "eval")
    assert scored.returncode == 0, scored.stderr
    mae = float(scored.stdout.split("MAE ")[1].split(" N")[0])
    assert np.isfinite(mae) and mae >= 0
    assert (folder / "eval" / "live_metrics.json").is_file()
    assert (folder / "eval" / "live_force.png").is_file()
    # the same frames reconstructed and evaluated offline give the same estimates: live's rest
    # reference is the recording's first frame however late it reached the estimator
    assert vbfe("reconstruct", session).returncode == 0
    offline = vbfe("evaluate", model, session, "--out", folder / "offline")
    assert offline.returncode == 0, offline.stderr
    with open(folder / "offline" / "predictions.csv") as rows:
        selected = load_model(model).for_protocol(DEFAULT_PROTOCOL).selected  # as live's
        by_frame = {int(r["frame"]): float(r[f"{selected}_n"]) for r in csv.DictReader(rows)}
    frame_of = {int(seq): i for i, seq in enumerate(seqs_in_order)}
    pairs = zip(stream.frame_seq, stream.force_n, strict=True)
    live = {frame_of[int(q)]: float(f[0]) for q, f in pairs}
    assert min(live) == 0  # the first frame was estimated: the rest reference
    both = sorted(set(live) & set(by_frame))
    assert len(both) == n
    np.testing.assert_allclose(
        [live[i] for i in both], [by_frame[i] for i in both], rtol=1e-5, atol=1e-6
    )


@pytest.mark.slow  # real time
def test_sigkill_of_live_record_keeps_the_estimates_up_to_the_last_flush(rig, tmp_path):
    """`vbfe live --record` killed (SIGKILL) a few seconds in: the recovered session holds
    the estimates of its frames as they were flushed, the newest within a flush interval
    (and one estimate's time) of the last flush, with the run's settings to score them."""
    import time

    from vbfe.acquire import recover_session

    folder, model, calib, toml = rig
    path = tmp_path / "killed.h5"
    proc = subprocess.Popen(
        [sys.executable, "-m", "vbfe.cli.main", "live", "--model", model, "--calib", calib]
        + ["--record", path, "--duration", "120", "--headless", "--config", toml],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        deadline, seen = time.monotonic() + 120, 0
        while seen < 8 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
            if path.exists():
                try:
                    with SessionReader(path) as reader:
                        seen = len(reader.estimates() or ())
                except Exception:  # noqa: BLE001 - not yet readable: the layout is being made
                    pass
        assert seen >= 8, proc.stderr.read() if proc.poll() is not None else "too slow"
        time.sleep(1.5)  # estimates after the first ones, some flushed, some not yet
    finally:
        proc.kill()
        proc.wait()
    fixed, _ = recover_session(path, tmp_path / "fixed.h5")
    with SessionReader(fixed) as reader:
        stream = reader.estimates()
        recorded = set(reader.stream_times("camera")[2].tolist())
        flushes = reader.clock_pairs()[:, 1]  # (UTC, host) at each flush
        interval = reader.attrs["flush_interval_s"]
    assert stream is not None and len(stream) >= seen
    assert set(stream.frame_seq.tolist()) <= recorded
    assert np.all(np.diff(stream.frame_seq) > 0) and np.isfinite(stream.force_n).all()
    assert stream.attrs["target"] == "magnitude" and stream.stages == list(STAGES)
    ready = stream.t_ready_host_ns
    step = np.max(np.diff(ready))  # the longest wait for an estimate
    assert 0 < flushes[-1] - ready[-1] < interval * 1e9 + step


def test_live_refuses_a_calibration_of_another_camera_mode(rig, tmp_path):
    folder, model, calib, _ = rig
    toml = tmp_path / "rig.toml"
    toml.write_text("[bench]\nwidth = 640\nheight = 360\n")
    result = vbfe(
        "live", "--model", model, "--calib", calib, "--duration", 1, "--headless", "--config", toml
    )
    assert result.returncode == 2
    assert "640x360" in result.stderr and "320x180" in result.stderr
    assert "Traceback" not in result.stderr


def test_live_window_runs_offscreen_and_closes_at_the_duration(rig):
    folder, model, calib, toml = rig
    result = vbfe("live", "--model", model, "--calib", calib, "--duration", 2, "--config", toml)
    assert result.returncode == 0, result.stderr
    estimates = int(result.stdout.split(" estimates from ")[0].split()[-1])
    assert estimates >= 1 and "Traceback" not in result.stderr


def test_live_publishes_estimates_over_lsl_and_udp(rig):
    """`vbfe live --lsl --udp` consumed by a pylsl inlet and a UDP socket: every estimate
    arrives with its frame's capture time, and the latency from capture to receipt is the
    estimator's own plus a short delivery (bench_streams prints its p95)."""
    import json
    import socket
    import time
    import uuid

    import pylsl

    folder, model, calib, toml = rig
    source = f"vbfe-test-{uuid.uuid4().hex[:8]}"
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(0.2)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "vbfe.cli.main",
            "live",
            "--model",
            model,
            "--calib",
            calib,
            "--duration",
            "6",
            "--headless",
            "--config",
            toml,
            "--lsl",
            source,
            "--udp",
            f"127.0.0.1:{receiver.getsockname()[1]}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        found = {
            name: pylsl.resolve_bypred(f"source_id='{source}-{name}'", timeout=60.0)
            for name in ("estimate", "trocar")
        }
        assert all(found.values()), "the live outlets never appeared"
        inlets = {name: pylsl.StreamInlet(info[0]) for name, info in found.items()}
        for inlet in inlets.values():
            inlet.open_stream(timeout=10.0)
        received, datagrams, trocar = [], [], 0
        until = time.monotonic() + 3.0
        while time.monotonic() < until:
            sample, stamp = inlets["estimate"].pull_sample(timeout=0.1)
            if sample is not None:
                received.append((pylsl.local_clock() - stamp, sample))
            trocar += len(inlets["trocar"].pull_chunk(timeout=0.0)[1])
            try:
                datagrams.append(json.loads(receiver.recv(65536)))
            except TimeoutError:
                pass
    finally:
        out, err = proc.communicate(timeout=120)
        receiver.close()
    assert proc.returncode == 0, err
    assert len(received) >= 5 and trocar >= 1000  # ~3 s of a 1 kHz trocar
    end_to_end = np.array([latency for latency, _ in received])
    estimator = np.array([sample[-1] for _, sample in received])
    assert np.all(end_to_end >= estimator)  # received after it was ready
    assert np.percentile(end_to_end - estimator, 95) < 0.25  # loopback delivery
    assert all(np.isfinite(sample[0]) for _, sample in received)
    by_frame_time = {round(sample[-2] * 1e9): sample for _, sample in received}
    matched = [d for d in datagrams if d["t_frame_host_ns"] in by_frame_time]
    assert len(matched) >= 3  # the same estimates came over UDP
    for d in matched:
        assert d["force_n"][0] == pytest.approx(by_frame_time[d["t_frame_host_ns"]][0])


def test_the_m_key_marks_the_live_recording(rig, tmp_path):
    import time

    from pyqtgraph.Qt import QtCore, QtTest, QtWidgets

    from vbfe.calib.calibration import load_calibration
    from vbfe.estimate.model_file import load_model
    from vbfe.live.estimator import FrameEstimator
    from vbfe.live.run import live_run
    from vbfe.live.viewer import LiveEstimateWindow

    folder, model, calib, toml = rig
    calibration = load_calibration(calib)
    estimator = FrameEstimator(load_model(model), calibration, scale=0.5)
    run = live_run(load_rig(toml), estimator, calibration, str(calib), tmp_path / "m.h5")
    run.start(1.5)
    window = LiveEstimateWindow(run, None)
    t_before = time.monotonic_ns()
    QtTest.QTest.keyClick(window, QtCore.Qt.Key.Key_M)
    t_after = time.monotonic_ns()
    while run.running():
        QtWidgets.QApplication.processEvents()
        time.sleep(0.05)
    window.close()
    run.stop()
    assert window.note == " | mark 1"
    with SessionReader(tmp_path / "m.h5") as reader:
        (event,) = reader.events()
    assert event["source"] == "mark" and event["text"] == "key M 1"
    assert t_before <= event["t_host_ns"] <= t_after


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _decoder(channel):
    """A decoder of the channel's messages made from its advertised schema alone."""
    import json

    from mcap_ros2._dynamic import generate_dynamic

    if channel["schemaEncoding"] == "ros2msg":
        assert channel["encoding"] == "cdr"
        return generate_dynamic(channel["schemaName"], channel["schema"])[channel["schemaName"]]
    assert channel["schemaEncoding"] == "jsonschema" and channel["encoding"] == "json"
    properties = json.loads(channel["schema"])["properties"]
    kinds = {"integer": int, "number": (int, float), "string": str, "array": list, "boolean": bool}

    def decode(data):
        message = json.loads(data)
        assert set(message) <= set(properties), set(message) - set(properties)
        for key, value in message.items():
            kind = properties[key]["type"]
            if value is None:  # NaN goes out as null
                assert kind == "number", key
            else:
                assert isinstance(value, kinds[kind]), key
                assert (kind == "boolean") == isinstance(value, bool), key
            if kind == "array":
                assert all(v is None or isinstance(v, int | float) for v in value), key
        return message

    return decode


def test_the_estimate_schema_is_one_the_foxglove_app_reads_and_nan_goes_out_as_null():
    """The app's rules refuse the schema the issue met (a float as ``["number", "null"]``)
    and read the one sent now, which names every field of the estimate record; an estimate
    without a usable cloud (NaN force and interval) decodes under it with nulls."""
    import dataclasses
    import json

    from tests.foxglove_client import app_schema_error
    from vbfe.live.estimator import LiveEstimate
    from vbfe.live.foxglove_server import estimate_json, estimate_schema

    def channel(schema):
        return {"encoding": "json", "schemaEncoding": "jsonschema"} | {
            "schemaName": "vbfe.LiveEstimate",
            "schema": json.dumps(schema),
        }

    schema = estimate_schema()
    assert app_schema_error(channel(schema)) is None
    assert {f.name for f in dataclasses.fields(LiveEstimate)} < set(schema["properties"])
    nullable = {"type": "array", "items": {"type": ["number", "null"]}}
    old = schema | {"properties": schema["properties"] | {"force_n": nullable}}
    assert app_schema_error(channel(old)) == (
        'Unsupported type ["number", "null"] for array item vbfe.LiveEstimate.force_n'
    )
    old = schema | {
        "properties": schema["properties"] | {"novelty_m": {"type": ["number", "null"]}}
    }
    assert "Unsupported type" in app_schema_error(channel(old))
    blank = LiveEstimate(np.array([np.nan]), 3, 10, 20, (0.1, 0.2, 0.0, 0.0), 0)
    message = _decoder(channel(schema))(json.dumps(estimate_json(blank, "magnitude")))
    assert message["force_n"] == [None] and message["lo_n"] == [None]
    assert message["novelty_m"] is None and message["ood"] is False and message["frame_seq"] == 3


def test_the_foxglove_server_speaks_the_subprotocols_docs_foxglove_md_names():
    """`foxglove.sdk.v1` and `foxglove.sdk.v1.1` connect; a client offering only the older
    `foxglove.websocket.v1` gets HTTP 400, as docs/how-to/foxglove.md says."""
    from tests.foxglove_client import SUBPROTOCOLS, FoxgloveClient
    from vbfe.live.foxglove_server import FoxgloveServer

    server = FoxgloveServer(0)
    server.open()
    try:
        for offered, chosen in (
            ("foxglove.sdk.v1", "foxglove.sdk.v1"),
            ("foxglove.sdk.v1.1", "foxglove.sdk.v1.1"),
            (SUBPROTOCOLS, "foxglove.sdk.v1"),  # both names, as Lichtblick >= 1.22.1 offers
        ):
            with FoxgloveClient("127.0.0.1", server.port, subprotocols=offered) as client:
                assert client.subprotocol == chosen
        with pytest.raises(ConnectionError, match=r"400(.|\n)*Missing expected sec-websocket"):
            FoxgloveClient("127.0.0.1", server.port, subprotocols="foxglove.websocket.v1")
    finally:
        server.on_stop(None)


@pytest.mark.slow  # real time
def test_the_closing_line_counts_each_clients_share_beside_a_slow_client():
    """A client that subscribes to the raw images and the trocar's wrench and stops reading,
    beside one that reads the wrench: the fast one gets all it was handed; the slow one, once
    the socket's buffers are full of images, gets less than it was handed (foxglove-sdk
    dropped the oldest for it) and the closing line names both clients' shares and the slow
    client as fallen behind, as the status every client is sent does; the server does not
    wait for it at the end (foxglove-sdk's stop would, forever)."""
    import re

    from tests.foxglove_client import FoxgloveClient
    from vbfe.acquire import Acquisition
    from vbfe.drivers.registry import open_rig
    from vbfe.drivers.rig import RigOptions
    from vbfe.live.foxglove_server import BACKLOG, FoxgloveServer
    from vbfe.messages.images import ImageCodec

    config = builtin_rig({"bench": dict(width=320, height=180, fps=10.0)})
    server = FoxgloveServer(0, ImageCodec("raw"))
    acquisition = Acquisition(open_rig(config, RigOptions(realtime=True)), listeners=(server,))
    acquisition.start()
    try:
        with (
            FoxgloveClient("127.0.0.1", server.port) as fast,
            FoxgloveClient("127.0.0.1", server.port) as slow,
        ):
            topics = {"/trocar/wrench", "/stereo/left/image_raw", "/stereo/right/image_raw"}
            fast.subscribe([fast.wait_for_topics(topics)["/trocar/wrench"]["id"]])
            slow.subscribe([c["id"] for c in slow.wait_for_topics(topics).values()])
            received = sum(1 for _ in fast.messages(4.0))  # the slow one reads nothing
            acquisition.stop()
            received += sum(1 for _ in fast.messages(0.5))
            late = sum(1 for _ in slow.messages(2.0))
    finally:
        acquisition.stop()
    line = server.summary()
    shares = [int(n) for n in re.findall(r"client \d+: (\d+)", line)]
    assert len(shares) == 2 and f"beyond {BACKLOG} queued" in line, line
    assert min(shares) >= 3000  # ~4 s of the 1 kHz trocar each
    # the fast client got every message handed for it: foxglove-sdk subscribes it before it
    # tells vbfe, so what it logged in between (35 at 1 kHz beside two busy processes) reached
    # the client uncounted; 0.2 s of wrench messages is the most that wait is allowed
    fast_share = min(shares, key=lambda n: abs(n - received))
    assert fast_share <= received <= fast_share + 200, (received, shares)
    slow_share = sum(shares) - fast_share
    assert late < slow_share - 500  # the slow one lost the oldest (fewer than handed)
    # foxglove-sdk's report of the overflow names the slow client, in the line and in the
    # status every client is sent (the fast one read it), never the fast one
    assert f"fell behind (queue full, oldest dropped): {slow.address};" in line, line
    told = [s["message"] for s in fast.statuses if "fell behind" in s["message"]]
    assert told and slow.address in told[0] and fast.address not in told[0], fast.statuses
    assert line.endswith("a client that stopped reading was left behind at the end")


@pytest.mark.slow
def test_foxglove_client_sees_images_wrench_estimates_and_clouds_live(rig):
    """`vbfe live --foxglove PORT` on the bench, watched by a WebSocket client on loopback as
    the Foxglove app would, with an LSL stream in the rig: the app reads every channel's
    schema (its own rules), every message decodes with the schema its channel advertised
    (ROS 2 message definitions, JSON schema); images are the camera's, the wrench is at the
    trocar's rate, estimates carry every field of the estimate record."""
    import time

    import cv2

    from tests.fakes.lsl_outlets import FakeRobot, unique
    from tests.foxglove_client import FoxgloveClient, app_schema_error

    folder, model, calib, toml = rig
    robot = FakeRobot(unique("live"), rate_hz=100.0, joints=2)
    with_stream = folder / "with_stream.toml"
    with_stream.write_text(toml.read_text() + f'[streams.robot]\nname = "{robot.name}"\n')
    port = _free_port()
    topics = {
        "/stereo/left/image_raw/compressed",
        "/stereo/right/image_raw/compressed",
        "/trocar/wrench",
        "/projector/events",
        "/vbfe/estimate",
        "/stereo/points",
        "/vbfe/streams/robot",
    }
    got: dict[str, list] = {topic: [] for topic in topics}
    with robot:
        proc = subprocess.Popen(
            [sys.executable, "-m", "vbfe.cli.main", "live", "--model", model, "--calib", calib]
            + ["--duration", "60", "--headless", "--config", with_stream]
            + ["--foxglove", str(port)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            with FoxgloveClient("127.0.0.1", port, timeout_s=120) as client:
                channels = client.wait_for_topics(topics, timeout_s=60)
                decoders = {topic: _decoder(channels[topic]) for topic in channels}
                client.subscribe([channels[topic]["id"] for topic in topics])
                start_ns = time.time_ns()
                for channel, log_time, data in client.messages(4.0):
                    got[channel["topic"]].append((log_time, decoders[channel["topic"]](data)))
            proc.send_signal(signal.SIGTERM)  # live ends on it as on its duration: exit 0
        finally:
            out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert " estimates from " in out  # the closing lines: it stopped, not died
    refused = {t: app_schema_error(c) for t, c in channels.items() if app_schema_error(c)}
    assert not refused and "/vbfe/streams/robot" in channels, refused
    assert len(got["/vbfe/streams/robot"]) >= 100  # 4 s of 100 Hz
    assert f"Foxglove: open ws://127.0.0.1:{port}" in err
    assert "Foxglove: sent" in out and "frames skipped for the viewer" in out
    for eye in ("left", "right"):
        images = got[f"/stereo/{eye}/image_raw/compressed"]
        assert len(images) >= 10  # ~4 s of 15 fps, some skipped for the viewer
        for log_time, image in images[:3]:
            assert image.format == "jpeg" and image.header.frame_id == f"stereo_{eye}_optical"
            pixels = cv2.imdecode(np.frombuffer(bytes(image.data), np.uint8), cv2.IMREAD_COLOR)
            assert pixels.shape == (180, 320, 3) and pixels.std() > 5  # the lit tissue
            assert log_time == image.header.stamp.sec * 10**9 + image.header.stamp.nanosec
            assert abs(log_time - start_ns) < 10e9  # Unix time
    wrenches = got["/trocar/wrench"]
    assert len(wrenches) >= 3000  # 4 s of a 1 kHz trocar, none dropped on loopback
    forces = np.array([[w.wrench.force.x, w.wrench.force.y, w.wrench.force.z] for _, w in wrenches])
    assert np.all(np.isfinite(forces)) and np.ptp(forces, axis=0).max() > 0
    estimates = [e for _, e in got["/vbfe/estimate"]]
    assert len(estimates) >= 3
    assert {"force_n", "frame_seq", "t_frame_host_ns", "latency_s", "target"} <= set(estimates[0])
    assert all(e["target"] == "magnitude" and len(e["force_n"]) == 1 for e in estimates)
    # the model's prediction interval around each estimate, and its out-of-distribution flag
    assert all(isinstance(e["ood"], bool) for e in estimates)
    bounded = [e for e in estimates if e["force_n"][0] is not None]
    assert bounded and all(e["lo_n"][0] < e["force_n"][0] < e["hi_n"][0] for e in bounded)
    clouds = [c for _, c in got["/stereo/points"]]
    assert 2 <= len(clouds) <= 10  # at most 2 a second
    assert clouds[0].width > 100 and clouds[0].point_step == 16
    points = np.frombuffer(bytes(clouds[0].data), np.float32).reshape(-1, 4)[:, :3]
    assert 0.03 < np.median(points[:, 2]) < 0.1  # the tissue, at the working distance (m)


def test_foxglove_options_are_checked_before_anything_is_recorded(tmp_path, capsys):
    """A busy port, a bad --images and --images without --foxglove: one line each, exit 2,
    no session file."""
    import socket

    from vbfe.cli.main import main

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        session = tmp_path / "s.h5"
        for args in (
            ["--foxglove", str(port)],
            ["--foxglove", "0", "--images", "gif"],
            ["--images", "png"],
            ["--foxglove", "70000"],
        ):
            assert main(["record", str(session), "--duration", "1", *args]) == 2
            assert not session.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("vbfe record: error: ") for line in err)
    assert f"--foxglove {port}: cannot serve" in err[0] and "another port" in err[0]
    assert "--images 'gif'" in err[1] and "--foxglove" in err[2] and "70000" in err[3]
