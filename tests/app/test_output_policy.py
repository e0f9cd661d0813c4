"""The output policy (vbfe.common.files) for every command that writes, enumerated from the real
argument parser so that a new command cannot be forgotten: an existing output is refused
without --overwrite, an output that is one of the command's inputs is refused even with it, and
a failing command leaves nothing behind. Most cases call the CLI's ``main`` in this process
(the checks run before any work); the subprocess cases are in test_output_faults.py."""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import time
from pathlib import Path

import h5py
import pytest

from tests.acquire.test_acquire_devices import write_bar_session
from vbfe.cli.main import build_parser, main

READ_ONLY = {"devices", "view", "calibrate check", "mark", "rig show"}  # mark: the recorder writes
APPENDS = {"calibrate capture", "calibrate projector-capture"}  # add files, never replace one
NEW_FILES_ONLY = {"live"}  # --record makes a new session; nothing to overwrite


def leaf_commands(
    parser: argparse.ArgumentParser, prefix: str = ""
) -> dict[str, argparse.ArgumentParser]:
    """Every runnable (sub)command of ``parser``, as 'calibrate color' → its parser."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return {prefix.strip(): parser}
    out = {}
    for name, sub in subs[0].choices.items():
        out.update(leaf_commands(sub, f"{prefix} {name}"))
    return out


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """Small inputs of every kind: a real session, a manifest listing it, a folder of views,
    and stand-ins whose content the checks never need to read."""
    d = tmp_path_factory.mktemp("inputs")
    session = d / "run.h5"
    write_bar_session(session, seconds=0.3)
    (d / "run.clouds.h5").write_bytes(b"sidecar stand-in")
    (d / "manifest.csv").write_text("path\nrun.h5\n")
    views = d / "views"
    views.mkdir()
    (views / "view_000_left.png").write_bytes(b"png stand-in")
    (views / "view_000_right.png").write_bytes(b"png stand-in")
    (d / "cal.yaml").write_text("not: a calibration\n")
    (d / "model.pt").write_bytes(b"model stand-in")
    (d / "forces.csv").write_bytes(bytes(range(256)) * 4)  # random bytes, not a CSV
    (d / "frames").mkdir()
    (d / "frames" / "000.npy").write_bytes(b"\x93NUMPY broken")
    return {"d": d, "session": session, "views": views}


def cases(i: dict[str, Path], out: Path) -> dict[str, tuple[list[str], list[str], list[str]]]:
    """Per writing command: (argv writing ``out``, argv writing one of its own inputs with
    --overwrite or [] when it has no file inputs, argv that fails on a broken input)."""
    d, s, v = str(i["d"]), str(i["session"]), str(i["views"])
    o = str(out)
    imp = ["--force-columns", "fz", "--time-column", "t"]
    return {
        "record": (
            ["record", o, "--duration", "0.1"],
            ["record", f"{d}/cal.yaml", "--calib", f"{d}/cal.yaml", "--overwrite"],
            ["record", o, "--duration", "0.1", "--calib", f"{d}/cal.yaml"],
        ),
        "console": (  # the session is always new (refused if it exists); screenshots replace
            ["console", "--record", f"{o}.h5", "--duration", "0.1", "--screenshot", o],
            [
                "console",
                "--calib",
                f"{d}/cal.yaml",
                "--record",
                f"{o}.h5",
                "--duration",
                "0.1",
                "--screenshot",
                f"{d}/cal.yaml",
                "--overwrite",
            ],
            [],
        ),
        "rig init": (["rig", "init", o], [], []),
        "upgrade": (
            ["upgrade", s, "-o", o],
            ["upgrade", s, "-o", s, "--overwrite"],
            ["upgrade", f"{d}/run.clouds.h5", "-o", o],
        ),
        "calibrate board": (
            ["calibrate", "board", str(out.with_suffix(""))],
            [],
            ["calibrate", "board", str(out.with_suffix("")), "--squares-x", "1"],
        ),
        "calibrate camera": (
            ["calibrate", "camera", v, "-o", o],
            ["calibrate", "camera", v, "-o", f"{v}/view_000_left.png", "--overwrite"],
            ["calibrate", "camera", v, "-o", o],
        ),
        "calibrate stereo": (
            ["calibrate", "stereo", v, "-o", o],
            [
                "calibrate",
                "stereo",
                "--left",
                f"{v}/*_left.png",
                "--right",
                f"{v}/*_right.png",
                "-o",
                f"{v}/view_000_left.png",
                "--overwrite",
            ],
            ["calibrate", "stereo", v, "-o", o],
        ),
        "calibrate export": (
            [
                "calibrate",
                "export",
                f"{d}/cal.yaml",
                "--format",
                "kalibr",
                "--out-dir",
                str(out.parent),
            ],
            ["calibrate", "export", f"{d}/cal-camchain.yaml", "--format", "kalibr", "--overwrite"],
            [
                "calibrate",
                "export",
                f"{d}/cal.yaml",
                "--format",
                "kalibr",
                "--out-dir",
                str(out.parent),
            ],
        ),
        "calibrate color": (
            ["calibrate", "color", f"{d}/cal.yaml", "-o", o],
            ["calibrate", "color", f"{d}/cal.yaml", "-o", f"{d}/cal.yaml", "--overwrite"],
            ["calibrate", "color", f"{d}/cal.yaml", "-o", o],
        ),
        "calibrate import": (
            ["calibrate", "import", f"{d}/cal.yaml", "-o", o],
            ["calibrate", "import", f"{d}/cal.yaml", "-o", f"{d}/cal.yaml", "--overwrite"],
            ["calibrate", "import", f"{d}/cal.yaml", "-o", o],
        ),
        "export": (
            ["export", s, "-o", o],
            ["export", s, "-o", s, "--overwrite"],
            ["export", f"{d}/model.pt", "-o", o],
        ),
        "report": (
            ["report", s, "-o", o],
            ["report", s, "-o", s, "--overwrite"],
            ["report", f"{d}/model.pt", "-o", o],
        ),
        "calibrate projector": (
            ["calibrate", "projector", v, "--calibration", f"{d}/cal.yaml", "-o", o],
            [
                "calibrate",
                "projector",
                v,
                "--calibration",
                f"{d}/cal.yaml",
                "-o",
                f"{d}/cal.yaml",
                "--overwrite",
            ],
            ["calibrate", "projector", v, "--calibration", f"{d}/cal.yaml", "-o", o],
        ),
        "import": (
            ["import", "clouds", f"{d}/frames", "--forces", f"{d}/forces.csv", "--out", o, *imp],
            [
                "import",
                "clouds",
                f"{d}/frames",
                "--forces",
                f"{d}/run.clouds.h5",
                "--out",
                f"{d}/run.clouds.h5",
                *imp,
                "--overwrite",
            ],
            ["import", "clouds", f"{d}/frames", "--forces", f"{d}/forces.csv", "--out", o, *imp],
        ),
        "verify-sync": (
            ["verify-sync", s, "--plot", o, "--no-store"],
            ["verify-sync", s, "--plot", s, "--overwrite"],
            ["verify-sync", f"{d}/model.pt", "--plot", o],
        ),
        "demo": (["demo", "--out", str(out.parent)], [], []),
        "train": (
            ["train", s, "--out", o],
            ["train", f"{d}/manifest.csv", "--out", f"{d}/run.clouds.h5", "--overwrite"],
            ["train", f"{d}/model.pt", "--out", o],
        ),
        "evaluate": (
            ["evaluate", f"{d}/model.pt", s, "--out", str(out.parent)],
            ["evaluate", f"{d}/model.pt", s, "--out", f"{d}/model.pt", "--overwrite"],
            ["evaluate", f"{d}/model.pt", s, "--out", str(out.parent / "report")],
        ),
        "reconstruct": (
            ["reconstruct", s, "--out", o],
            ["reconstruct", s, "--out", s, "--overwrite"],
            ["reconstruct", f"{d}/model.pt", "--out", o],
        ),
        "dataset": (
            ["dataset", d, "--manifest", o],
            [],
            ["dataset", f"{d}/missing", "--manifest", o],
        ),
        "inspect": (
            ["inspect", s, "--recover", o],
            ["inspect", s, "--recover", s, "--overwrite"],
            ["inspect", f"{d}/model.pt", "--recover", o],
        ),
        "live": (
            ["live", "--model", f"{d}/model.pt", "--calib", f"{d}/cal.yaml", "--record", o],
            [
                "live",
                "--model",
                f"{d}/model.pt",
                "--calib",
                f"{d}/cal.yaml",
                "--record",
                f"{d}/cal.yaml",
            ],
            [
                "live",
                "--model",
                f"{d}/model.pt",
                "--calib",
                f"{d}/cal.yaml",
                "--record",
                o,
                "--headless",
                "--duration",
                "1",
            ],
        ),
    }


def digests(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def one_error(capsys, *words: str) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("vbfe ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert all(w in lines[0] for w in words), lines[0]
    return lines[0]


def test_every_command_is_classified_and_every_writer_has_overwrite(inputs, tmp_path):
    commands = leaf_commands(build_parser())
    writers = set(cases(inputs, tmp_path / "x"))
    assert set(commands) == writers | READ_ONLY | APPENDS, set(commands) ^ (
        writers | READ_ONLY | APPENDS
    )
    for name in writers - NEW_FILES_ONLY:
        options = {o for a in commands[name]._actions for o in a.option_strings}
        assert "--overwrite" in options, name


@pytest.mark.parametrize(
    "command", sorted(cases({"d": Path(), "session": Path(), "views": Path()}, Path("x")))
)
def test_existing_output_refused_own_input_refused_nothing_left_on_failure(
    command, inputs, tmp_path, capsys
):
    before = digests(inputs["d"])
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / {"import": "out.clouds.h5", "dataset": "out.csv", "verify-sync": "out.png"}.get(
        command, "out.file"
    )
    existing, own_input, failing = cases(inputs, out)[command]
    if command == "calibrate board":
        out = out.with_suffix(".png")
    if command == "calibrate export":
        out = out_dir / "cal-camchain.yaml"
    out.write_bytes(b"keep me")

    assert main(existing) == 2
    one_error(
        capsys, "not empty" if command in ("demo", "evaluate") else "already exists", "--overwrite"
    )
    assert out.read_bytes() == b"keep me"

    if own_input:
        (inputs["d"] / "cal-camchain.yaml").write_text("kalibr: stand-in\n")
        before = digests(inputs["d"])
        assert main(own_input) == 2
        one_error(capsys, "input")

    if failing:
        out.unlink()
        assert main(failing) == 2, capsys.readouterr()
        one_error(capsys)
        assert list(out_dir.rglob("*")) == [], "left behind"
    assert digests(inputs["d"]) == before


def test_a_session_is_never_replaced_by_a_calibration_whatever_its_name(inputs, tmp_path, capsys):
    session = tmp_path / "looks_like.yaml"
    session.write_bytes(inputs["session"].read_bytes())
    kept = hashlib.sha256(session.read_bytes()).hexdigest()
    for argv in (
        ["calibrate", "color", str(session), "--overwrite"],
        ["calibrate", "color", str(inputs["d"] / "cal.yaml"), "-o", str(session), "--overwrite"],
        ["calibrate", "camera", str(inputs["views"]), "-o", str(session), "--overwrite"],
        ["train", str(inputs["session"]), "--out", str(session), "--overwrite"],
        ["reconstruct", str(inputs["session"]), "--out", str(session), "--overwrite"],
    ):
        assert main(argv) == 2, argv
        one_error(capsys, "session", str(session))
    assert hashlib.sha256(session.read_bytes()).hexdigest() == kept
    with h5py.File(session, "r") as f:
        assert f.attrs["format"] == "vbfe-session"


BAD_VALUES = [  # (rig config, command, words of the one error line)
    ("[record]\nflush_interval_s = inf\n", ["record", "{o}.h5"], "[record] flush_interval_s"),
    ("[record]\nflush_interval_s = nan\n", ["record", "{o}.h5"], "[record] flush_interval_s"),
    ("[bench]\nhold_s = -3\n", ["record", "{o}.h5"], "[bench] hold_s"),
    ("[bench]\nstiffness_n_per_m = 0\n", ["record", "{o}.h5"], "[bench] stiffness_n_per_m"),
    ("[bench]\nwidth = 100000\nheight = 100000\n", ["record", "{o}.h5"], "[bench] width"),
    ("[sgbm]\np1 = 100\np2 = 10\n", ["reconstruct", "{s}", "--out", "{o}.clouds.h5"], "[sgbm] p2"),
    ("[train]\nconv_channels = []\n", ["train", "{s}", "--out", "{o}.pt"], "[train] conv_channels"),
    ("", ["reconstruct", "{s}", "--workers", "0"], "--workers"),
    ("", ["verify-sync", "{s}", "--workers", "-3"], "--workers"),
    ("", ["calibrate", "capture", "{o}", "--max-frames", "-1"], "--max-frames"),
    ("", ["calibrate", "check", "{s}", "--max-depth-error-mm", "-1"], "--max-depth-error-mm"),
    ("", ["calibrate", "color", "{s}", "--frames", "0"], "--frames"),
    ("", ["live", "--model", "m.pt", "--calib", "{s}", "--scale", "0"], "--scale"),
    (
        "",
        [
            "import",
            "clouds",
            "{o}",
            "--forces",
            "f.csv",
            "--out",
            "{o}.clouds.h5",
            "--force-columns",
            "fz",
            "--time-column",
            "t",
            "--fps",
            "nan",
        ],
        "--fps",
    ),
    ("", ["calibrate", "capture", "{s}"], "is a file"),
    ("", ["calibrate", "projector-capture", "{s}"], "is a file"),
    ("", ["calibrate", "export", "{s}", "--format", "ros", "--out-dir", "{m}"], "is a file"),
    ("", ["demo", "--out", "{s}"], "is a file"),
]


@pytest.mark.parametrize("table, argv, words", BAD_VALUES)
def test_bad_values_are_one_line_naming_table_and_key(inputs, tmp_path, capsys, table, argv, words):
    argv = [
        a.format(s=inputs["session"], o=tmp_path / "out", m=inputs["d"] / "model.pt") for a in argv
    ]
    if table:
        (tmp_path / "rig.toml").write_text(table)
        argv += ["--config", str(tmp_path / "rig.toml")]
    with pytest.raises(SystemExit) if words.startswith("--") else contextlib.nullcontext():
        assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and words in err.splitlines()[-1], err
    assert not list(tmp_path.glob("out*"))


@pytest.mark.parametrize("content", [None, bytes(range(256))])
def test_a_config_that_is_a_folder_or_binary_is_one_line(tmp_path, capsys, content):
    config = tmp_path / "rig"
    if content is None:
        config.mkdir()
    else:
        config.write_bytes(content)
    assert main(["record", str(tmp_path / "x.h5"), "--config", str(config)]) == 2
    one_error(capsys, "rig config", str(config))


def test_plain_inspect_checks_every_chunk_of_a_small_session(inputs, tmp_path, capsys):
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(inputs["session"].read_bytes())
    with h5py.File(damaged, "r") as f:
        info = f["force/force_n"].id.get_chunk_info(0)
    with open(damaged, "r+b") as fh:  # one changed byte in the first force chunk
        fh.seek(info.byte_offset + info.size // 2)
        byte = fh.read(1)
        fh.seek(-1, 1)
        fh.write(bytes([byte[0] ^ 0xFF]))
    assert main(["inspect", str(inputs["session"])]) == 0
    assert "0 damaged" in capsys.readouterr().out
    assert main(["inspect", str(damaged)]) == 1
    out = capsys.readouterr().out
    assert "damaged   force/force_n: rows 0-" in out and "checksum" in out, out


def test_damaged_metadata_is_one_line_or_a_damage_report_never_a_traceback(
    inputs, tmp_path, capsys
):
    data = inputs["session"].read_bytes()
    damaged = tmp_path / "damaged.h5"
    for offset in range(200, 4096, 300):  # superblock, object headers, attribute messages
        changed = bytearray(data)
        changed[offset : offset + 8] = bytes(b ^ 0xFF for b in changed[offset : offset + 8])
        damaged.write_bytes(changed)
        for argv in (
            ["inspect", str(damaged)],
            ["reconstruct", str(damaged), "--out", str(tmp_path / "c.clouds.h5")],
        ):
            code = main(argv)
            err = capsys.readouterr().err
            assert code in (0, 1, 2) and "Traceback" not in err, (offset, argv, err)
            assert code != 2 or len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["damaged.h5"]


@pytest.mark.parametrize(
    "rows, words",
    [("0,1\n0.2,2\n0.1,3\n", "not in order"), ("0,1\nnan,2\n0.2,3\n", "not a number")],
)
def test_import_refuses_force_times_out_of_order_or_missing(tmp_path, capsys, rows, words):
    import numpy as np

    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(2):
        np.save(frames / f"{i:03d}.npy", np.random.default_rng(i).random((50, 3)))
    (tmp_path / "f.csv").write_text("t,fz\n" + rows)
    out = tmp_path / "x.clouds.h5"
    assert (
        main(
            [
                "import",
                "clouds",
                str(frames),
                "--forces",
                str(tmp_path / "f.csv"),
                "--out",
                str(out),
                "--force-columns",
                "fz",
                "--time-column",
                "t",
                "--fps",
                "10",
            ]
        )
        == 2
    )
    one_error(capsys, "f.csv", words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.csv", "frames"]


def test_an_unreachable_ray_head_is_one_line_at_once(inputs, capsys):
    started = time.monotonic()
    assert (
        main(
            [
                "reconstruct",
                str(inputs["session"]),
                "--executor",
                "ray",
                "--ray-address",
                "127.0.0.1:9",
            ]
        )
        == 2
    )
    one_error(capsys, "cannot reach the Ray cluster at 127.0.0.1:9")
    assert time.monotonic() - started < 5
