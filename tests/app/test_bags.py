"""MCAP export and bag import: read back with the mcap reader and the ROS 2 decoder, round trip
through `vbfe import bag`, and bags written by rosbags' own writers (rosbag2, ROS 1) with the
topic names a robot publishes."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_typestore

from tests.paths import DATA, REPO
from vbfe.acquire import (
    EstimateStream,
    SessionReader,
    record_session,
    store_analysis,
    store_estimates,
)
from vbfe.calib.calibration import Calibration
from vbfe.cli.main import main
from vbfe.rig_config import builtin_rig
from vbfe.truth import calibration_from_rig, true_rig

CORRECTION_NS = 7_000_000


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """A raw (lzf) session with a stored frame-time correction and live estimates (with their
    interval and flag), and an mjpeg one: 160x90 at 15 fps for 2 s."""
    folder = tmp_path_factory.mktemp("bags")
    config = builtin_rig({"bench": dict(width=160, height=90, fps=15.0)})
    calibration = calibration_from_rig(true_rig(config))
    paths = {}
    for name, compression in (("raw", "lzf"), ("jpeg", "mjpeg")):
        paths[name] = folder / f"{name}.h5"
        record_session(
            config,
            paths[name],
            duration_s=2.0,
            compression=compression,
            calibration_yaml=calibration.to_yaml_text(),
        )
    store_analysis(paths["raw"], {"frame_time_correction_ns": CORRECTION_NS})
    with SessionReader(paths["raw"]) as reader:
        n = reader.n_frames
        t_dev, t_host, seq = reader.stream_times("camera")
    store_estimates(
        paths["raw"],
        EstimateStream(
            force_n=np.linspace(0, 1, n)[:, None],
            frame_seq=seq,
            t_frame_host_ns=t_host,
            t_ready_host_ns=t_host + 20_000_000,
            stage_s=np.full((n, 1), 0.02),
            stages=["model"],
            attrs={"target": "magnitude", "outputs": 1},
            lo_n=np.linspace(0, 1, n)[:, None] - 0.1,
            hi_n=np.linspace(0, 1, n)[:, None] + 0.2,
            ood=np.arange(n) % 5 == 0,
        ),
    )
    return paths


def _decoded(path):
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        messages = [
            (channel.topic, message, decoded)
            for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False)
        ]
    return summary, messages


def _stamp(header):
    return header.stamp.sec * 10**9 + header.stamp.nanosec


def test_export_reads_back_with_the_mcap_reader_and_ros2_decoder(sessions, tmp_path):
    out = tmp_path / "raw.mcap"
    assert (
        main(
            [
                "export",
                str(sessions["raw"]),
                "--format",
                "mcap",
                "-o",
                str(out),
                "--compression",
                "zstd",
                "--images",
                "raw",
            ]
        )
        == 0
    )
    summary, messages = _decoded(out)
    assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {"zstd"}
    assert summary.statistics.message_count == len(messages)
    by_topic = {}
    for topic, message, decoded in messages:
        by_topic.setdefault(topic, []).append((message, decoded))
    with SessionReader(sessions["raw"]) as reader:
        n, forces = reader.n_frames, reader.forces_n()
        frame_t, force_t = reader.frame_times_ns(), reader.force_times_ns()
        assert int(reader.analysis()["frame_time_correction_ns"]) == CORRECTION_NS
        for eye in ("left", "right"):
            images = by_topic[f"/stereo/{eye}/image_raw"]
            assert len(images) == n
            for i, (_, image) in enumerate(images):
                assert image.encoding == "bgr8" and (image.width, image.height) == (160, 90)
                assert bytes(image.data) == getattr(reader.frame(i), eye).tobytes()
            assert len(by_topic[f"/stereo/{eye}/camera_info"]) == n
        wrenches = by_topic["/trocar/wrench"]
        assert len(wrenches) == len(forces)
        got = np.array(
            [[w.wrench.force.x, w.wrench.force.y, w.wrench.force.z] for _, w in wrenches]
        )
        np.testing.assert_array_equal(got, forces)
    stamps = np.array([_stamp(image.header) for _, image in by_topic["/stereo/left/image_raw"]])
    # Unix time (after 2020), the corrected frame times, on the same clock as the force
    assert stamps.min() > 1_577_836_800 * 10**9
    np.testing.assert_array_equal(np.diff(stamps), np.diff(frame_t))
    wrench_stamps = np.array([_stamp(w.header) for _, w in wrenches])
    np.testing.assert_array_equal(wrench_stamps - stamps[0], force_t - frame_t[0])
    for topic, items in by_topic.items():
        log_times = [m.log_time for m, _ in items]
        assert log_times == sorted(log_times), topic
    estimates = by_topic["/vbfe/estimate"]
    assert len(estimates) == n and estimates[-1][1].force_n == [1.0]
    assert estimates[0][1].axes == ["|F|"] and estimates[0][1].target == "magnitude"
    force = np.linspace(0, 1, n)
    np.testing.assert_allclose([e.lo_n[0] for _, e in estimates], force - 0.1)
    np.testing.assert_allclose([e.hi_n[0] for _, e in estimates], force + 0.2)
    assert [e.ood for _, e in estimates] == [k % 5 == 0 for k in range(n)]
    assert by_topic["/projector/events"][0][1].pattern == "debruijn-hsv"
    info = by_topic["/stereo/right/camera_info"][0][1]
    assert info.p[3] < 0 and info.distortion_model == "plumb_bob"  # P2[0,3] = -f·B


def test_estimates_without_interval_export_empty_bounds_and_no_flag(sessions, tmp_path):
    """A session recorded with a model that has no interval nor flag (or an older one)."""
    import shutil

    path = shutil.copy(sessions["raw"], tmp_path / "old.h5")
    with SessionReader(path) as reader:
        stored = reader.estimates()
    store_estimates(
        path,
        EstimateStream(
            stored.force_n,
            stored.frame_seq,
            stored.t_frame_host_ns,
            stored.t_ready_host_ns,
            stored.stage_s,
            stored.stages,
            stored.attrs,
        ),
    )
    out = tmp_path / "old.mcap"
    assert main(["export", str(path), "-o", str(out), "--images", "jpeg"]) == 0
    estimates = [d for topic, _, d in _decoded(out)[1] if topic == "/vbfe/estimate"]
    assert len(estimates) == len(stored) > 0
    assert all(e.lo_n == [] and e.hi_n == [] and e.ood is False for e in estimates)
    np.testing.assert_array_equal([e.force_n for e in estimates], stored.force_n)


def test_jpeg_session_exports_the_stored_jpeg_bytes(sessions, tmp_path):
    out = tmp_path / "jpeg.mcap"
    assert main(["export", str(sessions["jpeg"]), "-o", str(out)]) == 0  # lz4 by default
    summary, messages = _decoded(out)
    assert {c.compression for c in summary.chunk_indexes} == {"lz4"}
    left = [d for topic, _, d in messages if topic == "/stereo/left/image_raw/compressed"]
    with SessionReader(sessions["jpeg"]) as reader:
        assert [bytes(m.data) for m in left] == [
            reader.encoded_frame(i)[0] for i in range(reader.n_frames)
        ]
    assert left[0].format == "jpeg"


def test_export_refuses_to_overwrite(sessions, tmp_path, capsys):
    out = tmp_path / "x.mcap"
    out.write_bytes(b"keep")
    assert main(["export", str(sessions["raw"]), "-o", str(out)]) == 2
    assert main(["export", str(sessions["raw"]), "-o", str(sessions["raw"]), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("vbfe export: error:") for line in err)
    assert "--overwrite" in err[0] and "input" in err[1]
    assert out.read_bytes() == b"keep"


def _assert_same_session(original, imported, jpeg_bytes=False):
    with SessionReader(original) as a, SessionReader(imported) as b:
        assert a.n_frames == b.n_frames and a.frame_size == b.frame_size
        for i in range(a.n_frames):
            fa, fb = a.frame(i), b.frame(i)
            assert np.array_equal(fa.left, fb.left) and np.array_equal(fa.right, fb.right)
            if jpeg_bytes:
                assert a.encoded_frame(i) == b.encoded_frame(i)
        np.testing.assert_array_equal(a.forces_n(), b.forces_n())
        assert a.calibration_yaml() == b.calibration_yaml()
        np.testing.assert_array_equal(
            b.frame_times_ns() - b.frame_times_ns()[0], a.frame_times_ns() - a.frame_times_ns()[0]
        )
        np.testing.assert_array_equal(
            b.force_times_ns() - b.frame_times_ns()[0], a.force_times_ns() - a.frame_times_ns()[0]
        )
        assert [e.pattern for e in a.projector_events()] == [
            e.pattern for e in b.projector_events()
        ]
        assert b.metadata["conditions"] == a.metadata["conditions"]


@pytest.mark.parametrize("kind", ["raw", "jpeg"])
def test_export_then_import_bag_gives_the_same_session(sessions, tmp_path, kind):
    bag, back = tmp_path / f"{kind}.mcap", tmp_path / f"{kind}_back.h5"
    assert main(["export", str(sessions[kind]), "-o", str(bag)]) == 0
    assert main(["import", "bag", str(bag), "-o", str(back)]) == 0
    _assert_same_session(sessions[kind], back, jpeg_bytes=kind == "jpeg")


# -- bags made elsewhere: rosbags' own writers, a robot's topic names -----------------------
BAG_EPOCH_NS = 1_700_000_000 * 10**9  # the bags made here start at this Unix time


def _header(types, t_ns, frame_id, ros1=False):
    """A ``std_msgs/Header`` stamped ``t_ns`` (ROS 1's has a sequence number)."""
    stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    kwargs = {"seq": 0} if ros1 else {}
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id, **kwargs)


def _image_msg(types, header, image, encoding):
    """A ``sensor_msgs/Image`` of a 3-channel 8-bit ``image``."""
    height, width = image.shape[:2]
    return types["sensor_msgs/msg/Image"](
        header=header,
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=3 * width,
        data=image.reshape(-1),
    )


def _robot_messages(store, session, ros1, compressed):
    """(topic, msgtype, Unix ns, message) of a robot's stereo + wrench recording built from a
    session's frames, forces and calibration."""
    import cv2

    types = store.types

    def header(t, frame):
        return _header(types, t, frame, ros1)

    out = []
    with SessionReader(session) as reader:
        cal = Calibration.from_yaml_text(reader.calibration_yaml())
        t0 = BAG_EPOCH_NS
        frame_t = reader.frame_times_ns() - reader.frame_times_ns()[0] + t0
        for i in range(reader.n_frames):
            frame = reader.frame(i)
            for eye, image, K, D, R, P in (
                ("left", frame.left, cal.K1, cal.D1, cal.R1, cal.P1),
                ("right", frame.right, cal.K2, cal.D2, cal.R2, cal.P2),
            ):
                t = int(frame_t[i]) + (1_000_000 if eye == "right" else 0)  # 1 ms apart
                h = header(t, f"{eye}_camera")
                if compressed:
                    data = np.frombuffer(cv2.imencode(".png", image)[1].tobytes(), np.uint8)
                    msg = types["sensor_msgs/msg/CompressedImage"](
                        header=h, format="png", data=data
                    )
                    out.append(
                        (
                            f"/stereo/{eye}/image_raw/compressed",
                            "sensor_msgs/msg/CompressedImage",
                            t,
                            msg,
                        )
                    )
                else:
                    rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
                    msg = _image_msg(types, h, rgb, "rgb8")
                    out.append((f"/stereo/{eye}/image_raw", "sensor_msgs/msg/Image", t, msg))
                info = {
                    "D" if ros1 else "d": D,
                    "K" if ros1 else "k": K.ravel(),
                    "R" if ros1 else "r": R.ravel(),
                    "P" if ros1 else "p": P.ravel(),
                }
                roi = types["sensor_msgs/msg/RegionOfInterest"](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
                )
                out.append(
                    (
                        f"/stereo/{eye}/camera_info",
                        "sensor_msgs/msg/CameraInfo",
                        t,
                        types["sensor_msgs/msg/CameraInfo"](
                            header=h,
                            height=90,
                            width=160,
                            distortion_model="plumb_bob",
                            binning_x=0,
                            binning_y=0,
                            roi=roi,
                            **info,
                        ),
                    )
                )
        forces = reader.forces_n()
        force_t = reader.force_times_ns() - reader.frame_times_ns()[0] + t0
        Vector3 = types["geometry_msgs/msg/Vector3"]
        for i in range(len(forces)):
            t = int(force_t[i])
            wrench = types["geometry_msgs/msg/Wrench"](
                force=Vector3(*forces[i]), torque=Vector3(0.0, 0.0, 0.0)
            )
            out.append(
                (
                    "/force_sensor/wrench",
                    "geometry_msgs/msg/WrenchStamped",
                    t,
                    types["geometry_msgs/msg/WrenchStamped"](header=header(t, "ft"), wrench=wrench),
                )
            )
    return sorted(out, key=lambda m: m[2]), cal


def _write_robot_bag(path, session, ros1, compressed):
    if ros1:
        from rosbags.rosbag1 import Writer

        store = get_typestore(Stores.ROS1_NOETIC)
        writer, serialize = Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        store = get_typestore(Stores.ROS2_HUMBLE)
        writer, serialize = Writer(path, version=9), store.serialize_cdr
    messages, cal = _robot_messages(store, session, ros1, compressed)
    with writer:
        connections = {}
        for topic, msgtype, t, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], t, serialize(msg, msgtype))
    return cal


@pytest.mark.parametrize("ros1", [False, True], ids=["rosbag2", "ros1"])
def test_import_robot_bag_written_by_rosbags(sessions, tmp_path, ros1, capsys):
    bag = tmp_path / ("robot.bag" if ros1 else "robot_bag")
    cal = _write_robot_bag(bag, sessions["raw"], ros1, compressed=ros1)
    out = tmp_path / "robot.h5"
    assert main(["import", "bag", str(bag), "-o", str(out)]) == 0
    assert "calibration: camera_info" in capsys.readouterr().out
    with SessionReader(sessions["raw"]) as a, SessionReader(out) as b:
        assert b.n_frames == a.n_frames
        for i in (0, a.n_frames - 1):
            assert np.array_equal(a.frame(i).left, b.frame(i).left)
            assert np.array_equal(a.frame(i).right, b.frame(i).right)
        np.testing.assert_array_equal(b.forces_n(), a.forces_n())
        imported = Calibration.from_yaml_text(b.calibration_yaml())
    for name in ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q"):
        np.testing.assert_allclose(
            getattr(imported, name), getattr(cal, name), rtol=1e-9, atol=1e-12, err_msg=name
        )
    assert imported.B == pytest.approx(cal.B, rel=1e-12)


def test_reconstruct_works_on_an_imported_bag(sessions, tmp_path):
    """The calibration rebuilt from camera_info reconstructs the frames as the original does
    (160x90 is too small for the De Bruijn verification: plain SGBM)."""
    from vbfe.recon.clouds import CloudReader

    bag = tmp_path / "robot_bag"
    _write_robot_bag(bag, sessions["raw"], ros1=False, compressed=False)
    out = tmp_path / "robot.h5"
    assert main(["import", "bag", str(bag), "-o", str(out)]) == 0
    densities = []
    for session in (out, sessions["raw"]):
        clouds = tmp_path / f"{session.stem}.clouds.h5"
        assert (
            main(
                ["reconstruct", str(session), "--workers", "1", "--no-verify", "--out", str(clouds)]
            )
            == 0
        )
        with CloudReader(clouds) as reader:
            densities.append(reader.frame_table("valid_fraction"))
    assert len(densities[0]) == 30 and np.median(densities[0]) > 0.2
    np.testing.assert_allclose(densities[0], densities[1], atol=0.01)
    # the quality page of the robot's recording, with its clouds and camera_info calibration
    assert main(["report", str(out), "--clouds", str(tmp_path / "robot.clouds.h5")]) == 0
    page = out.with_suffix(".html").read_text()
    assert "median density" in page and "B</td><td>4.0000 mm" in page
    with SessionReader(sessions["raw"]) as reader:  # the robot's wrench samples, all of them
        assert f"<td>force samples</td><td>{len(reader.forces_n())}</td>" in page
    # the clouds go out as PointCloud2: x, y, z float32 and packed rgb, every point
    mcap = tmp_path / "with_clouds.mcap"
    assert (
        main(["export", str(out), "-o", str(mcap), "--clouds", str(tmp_path / "robot.clouds.h5")])
        == 0
    )
    clouds = [d for topic, _, d in _decoded(mcap)[1] if topic == "/stereo/points"]
    with CloudReader(tmp_path / "robot.clouds.h5") as reader:
        assert len(clouds) == reader.n_frames
        points, colors = reader.cloud(5)
    data = np.frombuffer(bytes(clouds[5].data), np.float32).reshape(-1, 4)
    assert clouds[5].width == len(points) and clouds[5].point_step == 16
    np.testing.assert_array_equal(data[:, :3], points)
    rgb = data[:, 3].view(np.uint32)
    np.testing.assert_array_equal(np.column_stack([rgb >> 16, (rgb >> 8) & 255, rgb & 255]), colors)


def test_ambiguous_topics_are_listed(sessions, tmp_path, capsys):
    bag = tmp_path / "robot_bag"
    _write_robot_bag(bag, sessions["raw"], ros1=False, compressed=False)
    out = tmp_path / "x.h5"
    assert (
        main(["import", "bag", str(bag), "-o", str(out), "--left", "/stereo/left/image_raw"]) == 0
    )
    assert (
        main(
            [
                "import",
                "bag",
                str(bag),
                "-o",
                str(out),
                "--overwrite",
                "--image",
                "/stereo/left/image_raw",
                "--force",
                "/nope",
            ]
        )
        == 2
    )
    assert (
        main(
            [
                "import",
                "bag",
                str(bag),
                "-o",
                str(tmp_path / "y.h5"),
                "--right",
                "/stereo/left/image_raw",
            ]
        )
        == 2
    )
    assert main(["import", "bag", str(Path(bag) / "missing"), "-o", str(tmp_path / "z.h5")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(err) == 3 and all(line.startswith("vbfe import: error: ") for line in err)
    assert "--force /nope: no such topic" in err[0] and "/force_sensor/wrench" in err[0]
    assert "cannot tell the stereo image topics apart" in err[1]
    assert "/stereo/right/image_raw (Image)" in err[1] and "--left and --right" in err[1]
    assert "does not exist" in err[2]
    assert not (tmp_path / "y.h5").exists() and not (tmp_path / "z.h5").exists()


@pytest.mark.parametrize("path", ["rosbag2_talker", "rosbag2_talker/talker.mcap"])
def test_a_rosbag2_recording_written_by_ros2_without_images_is_refused_in_one_line(
    tmp_path, capsys, path
):
    bag = DATA / path
    assert main(["import", "bag", str(bag), "-o", str(tmp_path / "x.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "vbfe import: error: the bag has no image topics (sensor_msgs/Image or "
        "CompressedImage); its topics: /parameter_events (ParameterEvent), "
        "/rosout (Log), /topic (String)"
    ]
    assert not (tmp_path / "x.h5").exists()


def test_side_by_side_topic_in_a_rosbag2_mcap_folder(sessions, tmp_path, capsys):
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    bag = tmp_path / "sbs_bag"
    with (
        SessionReader(sessions["raw"]) as reader,
        Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer,
    ):
        image = writer.add_connection(
            "/endoscope/image_raw", "sensor_msgs/msg/Image", typestore=store
        )
        force = writer.add_connection(
            "/ft/wrench", "geometry_msgs/msg/WrenchStamped", typestore=store
        )
        frame_t = reader.frame_times_ns() - reader.frame_times_ns()[0] + BAG_EPOCH_NS
        for i, frame in enumerate(reader.iter_frames()):
            t = int(frame_t[i])
            header = _header(types, t, "endoscope")
            both = np.hstack([frame.left, frame.right])
            writer.write(
                image,
                t,
                store.serialize_cdr(
                    _image_msg(types, header, both, "bgr8"), "sensor_msgs/msg/Image"
                ),
            )
            vector = types["geometry_msgs/msg/Vector3"]
            writer.write(
                force,
                t,
                store.serialize_cdr(
                    types["geometry_msgs/msg/WrenchStamped"](
                        header=header,
                        wrench=types["geometry_msgs/msg/Wrench"](
                            force=vector(0.0, 0.0, float(i)), torque=vector(0.0, 0.0, 0.0)
                        ),
                    ),
                    "geometry_msgs/msg/WrenchStamped",
                ),
            )
    out = tmp_path / "sbs.h5"
    assert main(["import", "bag", str(bag), "-o", str(out)]) == 2  # one image topic: which?
    assert "--image for one side-by-side topic" in capsys.readouterr().err
    assert main(["import", "bag", str(bag), "-o", str(out), "--image", "/endoscope/image_raw"]) == 0
    assert "calibration: none" in capsys.readouterr().out
    with SessionReader(sessions["raw"]) as a, SessionReader(out) as b:
        assert b.n_frames == a.n_frames and b.frame_size == (160, 90)
        assert np.array_equal(b.frame(7).left, a.frame(7).left)
        assert np.array_equal(b.frame(7).right, a.frame(7).right)
        np.testing.assert_array_equal(b.forces_n()[:, 2], np.arange(a.n_frames))
        assert b.calibration_yaml() is None


def test_damaged_bag_is_one_line_and_leaves_nothing(sessions, tmp_path, capsys):
    bag = tmp_path / "raw.mcap"
    assert main(["export", str(sessions["raw"]), "-o", str(bag)]) == 0
    data = bytearray(bag.read_bytes())
    data[len(data) // 3 : len(data) // 3 + 2000] = bytes(2000)  # inside a compressed chunk
    bag.write_bytes(bytes(data))
    capsys.readouterr()
    assert main(["import", "bag", str(bag), "-o", str(tmp_path / "x.h5")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(err) == 1 and "raw.mcap is damaged" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["raw.mcap"]


# -- image codecs: a bench session at the camera's 640x360 ----------------------------------
@pytest.fixture(scope="module")
def bench_640(tmp_path_factory):
    """1 s of the bench at 640x360 (the sizes scale with the frame count: the ratios are an
    8 s session's)."""
    path = tmp_path_factory.mktemp("codecs") / "bench.h5"
    config = builtin_rig({"bench": dict(width=640, height=360)})
    record_session(config, path, duration_s=1.0)
    return path


def _export_images(session, out, images):
    assert main(["export", str(session), "-o", str(out), "--images", images]) == 0
    _, messages = _decoded(out)
    return {
        eye: [d for topic, _, d in messages if topic.startswith(f"/stereo/{eye}/image_raw")]
        for eye in ("left", "right")
    }


def test_png_export_is_lossless_and_2_5x_smaller_than_raw_jpeg90_10x(bench_640, tmp_path):
    sizes, decoded = {}, {}
    for images in ("raw", "png", "jpeg:90"):
        out = tmp_path / f"{images.replace(':', '')}.mcap"
        decoded[images] = _export_images(bench_640, out, images)
        sizes[images] = out.stat().st_size
    # lossless cannot reach the 3x in a format Foxglove shows: the bench's sensor noise
    # (sigma 1 grey level) leaves 2.6 bits per sample after PNG's best predictor on a flat
    # image (3.07x; benchmarks/bench_export.py); zlib's run-length strategy gets 2.6x, its
    # default level 1 (before) 2.1x
    assert sizes["raw"] >= 2.5 * sizes["png"], sizes
    assert sizes["raw"] >= 10 * sizes["jpeg:90"], sizes
    with SessionReader(bench_640) as reader:
        n = reader.n_frames
        assert n >= 25 and all(len(decoded[k]["left"]) == n for k in decoded)
        psnr = []
        for eye in ("left", "right"):
            for i, (png, jpeg) in enumerate(
                zip(decoded["png"][eye], decoded["jpeg:90"][eye], strict=True)
            ):
                original = getattr(reader.frame(i), eye)
                assert png.format == "png" and jpeg.format == "jpeg"
                image = cv2.imdecode(np.frombuffer(bytes(png.data), np.uint8), cv2.IMREAD_COLOR)
                assert np.array_equal(image, original)  # pixel-identical
                lossy = cv2.imdecode(np.frombuffer(bytes(jpeg.data), np.uint8), cv2.IMREAD_COLOR)
                psnr.append(cv2.PSNR(lossy, original))
    assert min(psnr) > 30.0  # the same image, at JPEG 90's quality


def test_png_keeps_deflate_where_images_repeat():
    """Clean images with repeats (OpenCV's grey chessboard sample, Middlebury's cones) keep
    deflate's gain: the smaller of the two PNG encodings, pixel-identical."""
    from vbfe.messages.images import image_codec

    data = DATA
    # measured 3.9x and 2.5x; run-length alone gets 2.9x and 1.5x
    for path, ratio in (("opencv_stereo/left01.jpg", 3.5), ("middlebury_cones/im0.png", 2.3)):
        image = cv2.imread(str(data / path), cv2.IMREAD_COLOR)
        encoded = image_codec("png").encode(image)
        decoded = cv2.imdecode(np.frombuffer(encoded, np.uint8), cv2.IMREAD_COLOR)
        assert np.array_equal(decoded, image), path
        assert image.nbytes >= ratio * len(encoded), (path, image.nbytes / len(encoded))


def test_images_option_is_checked_in_one_line(sessions, tmp_path, capsys):
    for bad in ("gif", "jpeg:0", "jpeg:101", "png:3"):
        out = tmp_path / "x.mcap"
        assert main(["export", str(sessions["raw"]), "-o", str(out), "--images", bad]) == 2
        assert not out.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all("--images" in line and "png" in line for line in err)


# -- the Foxglove layout shipped in docs/ ---------------------------------------------------
LAYOUT = REPO / "docs" / "foxglove" / "vbfe-layout.json"


def _layout_topics(layout):
    """Every topic a panel of the layout reads: image topics, plot paths, 3D topics."""
    topics = set()
    for config in layout["configById"].values():
        topics |= {v for k, v in config.get("imageMode", {}).items() if k.endswith("Topic")}
        topics |= {path["value"].split(".")[0] for path in config.get("paths", [])}
        topics |= set(config.get("topics", {}))
    return topics


def _layout_plot_paths(layout):
    """The message paths the layout's plots read (``/topic.field[index]``)."""
    return [p["value"] for c in layout["configById"].values() for p in c.get("paths", [])]


def _layout_panels(node):
    return (
        {node}
        if isinstance(node, str)
        else set().union(*(_layout_panels(node[side]) for side in ("first", "second")))
    )


def test_layout_names_only_topics_the_export_and_the_live_server_write(sessions, tmp_path):
    import json

    from tests.foxglove_client import FoxgloveClient
    from vbfe.acquire import Acquisition
    from vbfe.drivers.registry import open_rig
    from vbfe.drivers.rig import RigOptions
    from vbfe.live.foxglove_server import FoxgloveServer

    layout = json.loads(LAYOUT.read_text())
    assert _layout_panels(layout["layout"]) == set(layout["configById"])
    wanted = _layout_topics(layout)
    assert {"/trocar/wrench", "/stereo/points", "/vbfe/estimate"} <= wanted
    # the export of a session with live estimates and its clouds (default --images png)
    clouds, bag = tmp_path / "raw.clouds.h5", tmp_path / "raw.mcap"
    assert (
        main(
            ["reconstruct", str(sessions["raw"]), "--workers", "1", "--no-verify"]
            + ["--out", str(clouds)]
        )
        == 0
    )
    assert main(["export", str(sessions["raw"]), "-o", str(bag), "--clouds", str(clouds)]) == 0
    exported = {}
    for topic, _, decoded in _decoded(bag)[1]:
        exported.setdefault(topic, decoded)
    assert wanted <= exported.keys(), wanted - exported.keys()
    # every plotted field is in the exported message, e.g. the estimate's interval
    paths = _layout_plot_paths(layout)
    assert {"/vbfe/estimate.lo_n[0]", "/vbfe/estimate.hi_n[0]"} <= set(paths)
    for path in paths:
        topic, *fields = path.split(".")
        value = exported[topic]
        for name in fields:
            name, _, index = name.partition("[")
            value = getattr(value, name)
            value = value[int(index.rstrip("]"))] if index else value
        assert isinstance(value, float), path
    # the live server (a live run's: with estimates and clouds) over the bench
    config = builtin_rig({"bench": dict(width=160, height=90, fps=15.0)})
    server = FoxgloveServer(0, target="magnitude")
    acquisition = Acquisition(open_rig(config, RigOptions(realtime=True)), listeners=(server,))
    acquisition.start()
    try:
        with FoxgloveClient("127.0.0.1", server.port) as client:
            channels = client.wait_for_topics(wanted, timeout_s=10.0)  # TimeoutError: which
    finally:
        acquisition.stop()
    estimate = json.loads(channels["/vbfe/estimate"]["schema"])["properties"]
    for path in paths:
        topic, name = path.split(".")[0], path.split(".")[1].partition("[")[0]
        if topic == "/vbfe/estimate":  # the live estimate is JSON: its schema names the field
            assert estimate[name]["type"] == "array", path


def test_the_fast_wrench_packing_gives_rosbags_own_cdr_bytes():
    from vbfe.messages import builders

    t_ns = np.array([1_700_000_000_123_456_789, 1_700_000_001_000_000_001, 2_000_000_000 * 10**9])
    forces = np.array([[0.1, -0.2, 3.5], [1e-3, 2.0, -7.25], [np.nan, np.inf, 0.0]])
    by_rosbags = [
        builders.cdr(builders.wrench(int(t), dict(zip("xyz", f, strict=True))), builders.WRENCH)
        for t, f in zip(t_ns, forces, strict=True)
    ]
    assert builders.wrench_cdr(t_ns, forces) == by_rosbags
