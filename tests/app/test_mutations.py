"""Mutation harness: damaged sessions, calibrations, models and rig configs through the CLI.

From one small valid set of files (a simulated session, its calibration, point clouds, a tiny
model and a rig config) every test generates damaged variants (each dataset and attribute
deleted, files truncated and overwritten, dtypes and shapes changed, nodes and keys removed,
NaN values, wrong types and unknown keys for every config key) and runs each command that reads
that kind of file on each. A damaged input must end in exit status 2 with one
``vbfe <command>: error:`` line naming the file (or the config table and key), never a
traceback; a harmless change (e.g. ground truth removed) may also succeed. Cases run in-process
(``vbfe.cli.main.main``); ``test_representative_cases_through_subprocesses`` runs a subset as
real processes. Each test reports how many cases it generated.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from tests.calibration_nodes import STEREO_MATRICES
from vbfe.cli.main import main
from vbfe.common.config import default_config, read_toml

SMALL_RIG = """\
[bench]
width = 320
height = 180
fps = 15.0
hold_s = 0.2

[train]
epochs = 2
batch_size = 4
n_points = 32
conv_channels = [8, 16]
head_channels = [8]
threads = 1
cnn_epochs = 2
"""
RECORD_S = "0.4"

# Session datasets every reader needs; everything else (truth, clock fits, analysis) is optional.
REQUIRED_SESSION_PREFIXES = ("camera", "force", "projector", "gaps", "clock_pairs")
REQUIRED_SESSION_ATTRS = {"/": ("format",), "camera": ("width", "height")}
REQUIRED_CALIBRATION_NODES = ("format", "image_width", "image_height", *STEREO_MATRICES)


@dataclass
class Case:
    """One damaged input and what must happen when a command reads it."""

    name: str
    argv: list[str]
    names: tuple[str, ...]  # the error line must contain one of these
    must_fail: bool = True


def run_cli(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[object, str]:
    """Exit code (or the escaped exception) and stderr of ``vbfe argv`` run in-process."""
    capsys.readouterr()
    try:
        code: object = main(argv)
    except SystemExit as exc:
        code = exc.code
    except BaseException as exc:  # noqa: BLE001 - an escaping exception is a traceback
        code = f"traceback {type(exc).__name__}: {str(exc)[:150]}"
    return code, capsys.readouterr().err


def judge(case: Case, code: object, err: str) -> str | None:
    """What is wrong with the outcome of a case, or None."""
    command = case.argv[0]
    if isinstance(code, str):
        return code
    lines = [line for line in err.replace("\r", "\n").splitlines() if ": error:" in line]
    if code != 2:
        if case.must_fail:
            return f"exit {code} (expected 2)"
        return None if not lines else f"exit {code} with error line {lines}"
    if len(lines) != 1 or not lines[0].startswith(f"vbfe {command}: error:"):
        return f"error lines {lines!r}"
    if not any(name in lines[0] for name in case.names):
        return f"error does not name {case.names[0]}: {lines[0]}"
    return None


def run_cases(cases: list[Case], capsys: pytest.CaptureFixture) -> None:
    """Run every case, then fail once listing the bad outcomes (and always print the count)."""
    failures = []
    for case in cases:
        code, err = run_cli(case.argv, capsys)
        problem = judge(case, code, err)
        if problem:
            failures.append(f"{case.name}: {' '.join(case.argv[:2])}: {problem}")
    with capsys.disabled():
        print(f"\n[mutations] {len(cases)} cases, {len(failures)} failed")
    assert not failures, f"{len(failures)} of {len(cases)} cases failed:\n" + "\n".join(failures)


# --- the valid corpus -------------------------------------------------------------------------
@dataclass
class Corpus:
    folder: Path
    rig: Path
    session: Path
    calibration: Path
    model: Path


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Corpus:
    """A small simulated session, its exact calibration, point clouds and a tiny model."""
    from vbfe.drivers.sim import SimBench
    from vbfe.truth import calibration_from_rig

    folder = tmp_path_factory.mktemp("corpus")
    rig = folder / "rig.toml"
    rig.write_text(SMALL_RIG)
    session, calibration, model = folder / "s.h5", folder / "calib.yaml", folder / "m.pt"
    bench = SimBench.from_config(read_toml(rig, "rig config")["bench"])
    calibration_from_rig(bench.rig).save(calibration)
    assert (
        main(
            [
                "record",
                str(session),
                "--duration",
                RECORD_S,
                "--config",
                str(rig),
                "--calib",
                str(calibration),
            ]
        )
        == 0
    )
    assert main(["reconstruct", str(session), "--workers", "1", "--config", str(rig)]) == 0
    assert main(["train", str(session), "--out", str(model), "--config", str(rig)]) == 0
    return Corpus(folder, rig, session, calibration, model)


_counter = iter(range(10**6))


def fresh(corpus: Corpus, suffix: str, stem: str = "case") -> Path:
    """A new path in the corpus folder."""
    return corpus.folder / f"{stem}{next(_counter)}{suffix}"


# --- session mutations ---------------------------------------------------------------------
def _h5_objects(path: Path) -> tuple[list[str], list[tuple[str, str]]]:
    names: list[str] = []
    with h5py.File(path, "r") as f:
        attrs: list[tuple[str, str]] = [("/", a) for a in f.attrs]

        def visit(name: str, obj: h5py.HLObject) -> None:
            names.append(name)
            attrs.extend((name, a) for a in obj.attrs)

        f.visititems(visit)
    return names, attrs


def _required(name: str) -> bool:
    return name.split("/")[0] in REQUIRED_SESSION_PREFIXES and not name.startswith("clock/")


def session_mutations(valid: Path, out: Callable[[], Path]) -> Iterator[tuple[str, Path, bool]]:
    """``(description, damaged copy, must_fail)`` for every damage of a session file."""
    names, attrs = _h5_objects(valid)
    size = valid.stat().st_size
    for name in names:
        path = out()
        shutil.copy(valid, path)
        with h5py.File(path, "r+") as f:
            del f[name]
        yield f"delete {name}", path, _required(name)
    for obj, attr in attrs:
        path = out()
        shutil.copy(valid, path)
        with h5py.File(path, "r+") as f:
            del f[obj].attrs[attr]
        yield f"delete attr {obj}@{attr}", path, attr in REQUIRED_SESSION_ATTRS.get(obj, ())
    for fraction in (0.0, 0.001, 0.1, 0.5, 0.9, 0.999):
        path = out()
        path.write_bytes(valid.read_bytes()[: int(size * fraction)])
        yield f"truncate at {fraction:.1%}", path, True
    rng = np.random.default_rng(0)
    for where, start, length, must in (
        ("head", 0, 4096, True),
        ("head+sb", 8, 64, True),
        ("tail", size - 8192, 8192, False),
        ("middle", size // 2, 4096, False),
    ):
        path = out()
        data = bytearray(valid.read_bytes())
        data[start : start + length] = rng.integers(0, 256, length, dtype=np.uint8).tobytes()
        path.write_bytes(bytes(data))
        yield f"random bytes over {where}", path, must
    for name, make in (
        ("camera/left", lambda a: a[..., 0]),
        ("camera/right", lambda a: a[:, :10]),
        ("force/force_n", lambda a: a[:, :2]),
        ("force/force_n", lambda a: a.astype("S8")),
        ("force/t_host_ns", lambda a: a.astype(np.float32)),
        ("force/t_host_ns", lambda a: a.astype("S20")),
        ("camera/t_device_ns", lambda a: a[:, None].repeat(2, 1)),
        ("camera/seq", lambda a: a.astype("S20")),
        ("projector/pattern", lambda a: np.arange(len(a))),
        ("gaps", lambda a: np.zeros((2, 3))),
        ("clock_pairs", lambda a: a.astype("S30")),
    ):
        path = out()
        shutil.copy(valid, path)
        with h5py.File(path, "r+") as f:
            changed = make(f[name][()])
            del f[name]
            f[name] = changed
        yield f"{name} changed to {changed.dtype} {changed.shape}", path, True
    path = out()
    shutil.copy(valid, path)
    with h5py.File(path, "r+") as f:
        f.attrs["metadata_json"] = "{not json"
    yield "metadata_json not JSON", path, True
    path = out()
    shutil.copy(valid, path)
    with h5py.File(path, "r+") as f:
        f["camera"].attrs["width"] = "wide"
    yield "camera@width a string", path, True


def _session_corpus(corpus: Corpus) -> list[tuple[str, Path, bool]]:
    """The damaged sessions, generated once per module."""
    if not hasattr(corpus, "_sessions"):
        corpus._sessions = list(
            session_mutations(corpus.session, lambda: fresh(corpus, ".h5", "s"))
        )
    return corpus._sessions


SESSION_COMMANDS: dict[str, Callable[[Path, Corpus], list[str]]] = {
    "inspect": lambda p, c: ["inspect", str(p)],
    "inspect --recover": lambda p, c: ["inspect", str(p), "--recover", str(fresh(c, ".h5", "r"))],
    "verify-sync": lambda p, c: [
        "verify-sync",
        str(p),
        "--no-store",
        "--plot",
        str(fresh(c, ".png")),
    ],
    "reconstruct": lambda p, c: [
        "reconstruct",
        str(p),
        "--calib",
        str(c.calibration),
        "--workers",
        "1",
        "--config",
        str(c.rig),
        "--out",
        str(fresh(c, ".clouds.h5")),
    ],
    "view": lambda p, c: ["view", str(p)],
}


@pytest.fixture
def headless_viewer(monkeypatch: pytest.MonkeyPatch) -> None:
    """`vbfe view` builds its window offscreen and returns instead of waiting for the user."""
    from PySide6 import QtWidgets

    monkeypatch.setattr(QtWidgets.QApplication, "exec", lambda self: 0)


# commands that do real work on a readable session run only the damages that must fail
# (inspect and --recover run every damage)
HEAVY = ("reconstruct", "view", "verify-sync")


@pytest.mark.parametrize("command", sorted(SESSION_COMMANDS))
def test_damaged_sessions(corpus, capsys, headless_viewer, command):
    sessions = _session_corpus(corpus)
    cases = [
        Case(
            f"session {what}", SESSION_COMMANDS[command](path, corpus), (str(path), path.name), must
        )
        for what, path, must in sessions
        if must or command not in HEAVY
    ]
    run_cases(cases, capsys)


@pytest.mark.slow
def test_damaged_sessions_for_training(corpus, capsys):
    """`vbfe train` reads the session next to its clouds sidecar. Training never opens the
    ground truth, so of its deletions only the whole group's is run (each case trains ~6 s)."""
    cases = []
    for what, path, must in _session_corpus(corpus):
        if not what.startswith("delete ") or what.startswith(("delete attr", "delete truth/")):
            continue
        shutil.copy(corpus.session.with_suffix(".clouds.h5"), path.with_suffix(".clouds.h5"))
        cases.append(
            Case(
                f"session {what}",
                [
                    "train",
                    str(path),
                    "--config",
                    str(corpus.rig),
                    "--out",
                    str(fresh(corpus, ".pt")),
                ],
                (str(path), path.name),
                must,
            )
        )
    run_cases(cases, capsys)


# --- calibration mutations -------------------------------------------------------------------
def _storage_nodes(path: Path) -> dict[str, object]:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    root = fs.root()
    nodes: dict[str, object] = {}
    for name in root.keys():
        node = fs.getNode(name)
        if node.isSeq():
            nodes[name] = [node.at(i).string() for i in range(node.size())]
        elif node.isString():
            nodes[name] = node.string()
        elif node.isMap() and node.getNode("dt").empty():
            continue  # the info map: optional, its damage is generated separately
        elif node.isMap():
            nodes[name] = node.mat()
        else:
            nodes[name] = node.real() if not float(node.real()).is_integer() else int(node.real())
    fs.release()
    return nodes


DELETE = object()


def write_storage(path: Path, nodes: dict[str, object]) -> Path:
    """Write nodes as OpenCV FileStorage YAML (no escaping games: only numbers and matrices)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    for name, value in nodes.items():
        if value is DELETE:
            continue
        if isinstance(value, list):
            fs.startWriteStruct(name, cv2.FileNode_SEQ)
            for piece in value:
                fs.write("", piece)
            fs.endWriteStruct()
        elif isinstance(value, dict):
            fs.startWriteStruct(name, cv2.FileNode_MAP)
            for k, v in value.items():
                fs.write(k, v)
            fs.endWriteStruct()
        else:
            fs.write(name, value)
    fs.release()
    return path


def calibration_mutations(valid: Path, out: Callable[[], Path]) -> Iterator[tuple[str, Path, bool]]:
    """``(description, damaged copy, must_fail)`` for every damage of a calibration file."""
    nodes = _storage_nodes(valid)
    for name in nodes:
        yield (
            f"delete {name}",
            write_storage(out(), {**nodes, name: DELETE}),
            name in REQUIRED_CALIBRATION_NODES,
        )
    for name, value in nodes.items():
        if isinstance(value, np.ndarray):
            nan = value.copy()
            nan.flat[0] = np.nan
            yield f"NaN in {name}", write_storage(out(), {**nodes, name: nan}), True
            yield (f"{name} is 2x2", write_storage(out(), {**nodes, name: np.eye(2)}), True)
            yield f"{name} is a number", write_storage(out(), {**nodes, name: 5}), True
            yield (f"{name} is a map", write_storage(out(), {**nodes, name: {"a": 1}}), True)
    for name in ("image_width", "image_height"):
        yield (f"{name} is a string", write_storage(out(), {**nodes, name: "wide"}), True)
        yield f"{name} is 0", write_storage(out(), {**nodes, name: 0}), True
    yield (
        "other image size",
        write_storage(out(), {**nodes, "image_width": 640, "image_height": 360}),
        True,
    )
    yield "info is a number", write_storage(out(), {**nodes, "info": 3}), True
    yield "info is a list", write_storage(out(), {**nodes, "info": ["{no"]}), True
    yield (
        "old info does not decode",
        write_storage(
            out(), {**{k: v for k, v in nodes.items() if k != "info"}, "info_json_base64": ["{no"]}
        ),
        True,
    )
    text = valid.read_text()
    for what, content in (
        ("empty", ""),
        ("JSON", '{"K1": [1, 2, 3]}'),
        ("JSON list", "[1, 2]"),
        ("binary", bytes(range(256)).decode("latin-1")),
        ("YAML list", "%YAML:1.0\n---\n- 1\n- 2\n"),
        ("truncated 50%", text[: len(text) // 2]),
        ("truncated 90%", text[: int(len(text) * 0.9)]),
    ):
        path = out()
        path.write_text(content, encoding="latin-1")
        yield what, path, True


CALIBRATION_COMMANDS: dict[str, Callable[[Path, Corpus], list[str]]] = {
    "calibrate check": lambda p, c: ["calibrate", "check", str(p), "--against", str(c.calibration)],
    "calibrate check --against": lambda p, c: [
        "calibrate",
        "check",
        str(c.calibration),
        "--against",
        str(p),
    ],
    "reconstruct --calib": lambda p, c: [
        "reconstruct",
        str(c.session),
        "--calib",
        str(p),
        "--workers",
        "1",
        "--config",
        str(c.rig),
        "--out",
        str(fresh(c, ".clouds.h5")),
    ],
    "record --calib": lambda p, c: [
        "record",
        str(fresh(c, ".h5", "rec")),
        "--duration",
        "0.2",
        "--config",
        str(c.rig),
        "--calib",
        str(p),
    ],
}


@pytest.mark.parametrize("command", sorted(CALIBRATION_COMMANDS))
def test_damaged_calibrations(corpus, capsys, command):
    if not hasattr(corpus, "_calibrations"):
        corpus._calibrations = list(
            calibration_mutations(corpus.calibration, lambda: fresh(corpus, ".yaml", "c"))
        )
    # reconstruct names the session and its image size when the calibration's size differs
    other = ("calibration is for",) if command.startswith("reconstruct") else ()
    cases = [
        Case(
            f"calibration {what}",
            CALIBRATION_COMMANDS[command](path, corpus),
            (str(path), path.name, *(other if what == "other image size" else ())),
            must,
        )
        for what, path, must in corpus._calibrations
    ]
    run_cases(cases, capsys)


# --- model mutations ----------------------------------------------------------------------
def model_mutations(valid: Path, out: Callable[[], Path]) -> Iterator[tuple[str, Path, bool]]:
    """``(description, damaged copy, must_fail)`` for every damage of a model file."""
    import torch

    payload = torch.load(valid, weights_only=True)

    def save(changed: dict) -> Path:
        path = out()
        torch.save(changed, path)
        return path

    for key in payload:
        # metadata, and what model files written before intervals and flags lack
        optional = key in ("vbfe_version", "created_unix_ns", "interval", "novelty", "disagreement")
        yield f"delete {key}", save({k: v for k, v in payload.items() if k != key}), not optional
    estimators = payload["estimators"]

    def with_pointnet(**changes: object) -> dict:
        return {
            **payload,
            "estimators": {**estimators, "pointnet": {**estimators["pointnet"], **changes}},
        }

    state = estimators["pointnet"]["state_dict"]
    for key in list(state)[::3]:  # BatchNorm rebuilds a missing batch counter: harmless
        yield (
            f"delete weight {key}",
            save(with_pointnet(state_dict={k: v for k, v in state.items() if k != key})),
            not key.endswith("num_batches_tracked"),
        )
    for key in [k for k in state if state[k].dtype.is_floating_point][::3]:
        yield (
            f"{key} wrong shape",
            save(with_pointnet(state_dict={**state, key: torch.zeros(2, 2, 2)})),
            True,
        )
        nan = state[key].clone()
        nan.view(-1)[0] = float("nan")
        yield f"NaN in {key}", save(with_pointnet(state_dict={**state, key: nan})), True
    hparams = estimators["pointnet"]["hparams"]
    for key, value in (
        ("conv_channels", [4, 4]),
        ("n_outputs", 3),
        ("dropout", "high"),
        ("unknown", 1),
    ):
        yield (
            f"hparams {key}={value!r}",
            save(with_pointnet(hparams={**hparams, key: value})),
            True,
        )
    yield "hparams not a dict", save(with_pointnet(hparams=[1, 2])), True
    yield "state_dict not a dict", save(with_pointnet(state_dict=[1])), True
    for key, value in (("n_points", "many"), ("target", "torque"), ("unknown_key", 1)):
        yield (
            f"config {key}={value!r}",
            save({**payload, "config": {**payload["config"], key: value}}),
            True,
        )
    yield (
        "baselines broken",
        save({**payload, "estimators": {**estimators, "mean": {"x": 1}}}),
        True,
    )
    yield (
        "selected model missing",
        save(
            {
                **payload,
                "selected": "ridge_height_map",
                "estimators": {k: v for k, v in estimators.items() if k != "ridge_height_map"},
            }
        ),
        True,
    )
    for name in ("ridge_height_map", "cnn_depth_change"):
        yield (
            f"{name} broken",
            save(
                {
                    **payload,
                    "estimators": {
                        **estimators,
                        name: {
                            **estimators[name],
                            "kind": estimators[name]["kind"],
                            "size" if name.startswith("ridge") else "state_dict": "abc",
                        },
                    },
                }
            ),
            True,
        )
    yield (
        "ensemble without members",
        save(
            {
                **payload,
                "estimators": {
                    **estimators,
                    "ensemble_cnn_hooke": {**estimators["ensemble_cnn_hooke"], "members": []},
                },
            }
        ),
        True,
    )
    history = estimators["mlp_displacement_history"]
    yield (
        "history baseline layers broken",
        save(
            {
                **payload,
                "estimators": {
                    **estimators,
                    "mlp_displacement_history": {**history, "layers": "abc"},
                },
            }
        ),
        True,
    )
    data = valid.read_bytes()
    for fraction in (0.0, 0.3, 0.9):
        path = out()
        path.write_bytes(data[: int(len(data) * fraction)])
        yield f"truncate at {fraction:.0%}", path, True


def test_damaged_models(corpus, capsys):
    cases = [
        Case(
            f"model {what}",
            ["evaluate", str(path), str(corpus.session), "--out", str(fresh(corpus, "", "eval"))],
            (str(path), path.name),
            must,
        )
        for what, path, must in model_mutations(corpus.model, lambda: fresh(corpus, ".pt", "m"))
    ]
    run_cases(cases, capsys)


# --- rig config mutations ----------------------------------------------------------------------
def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, float) and math.isinf(value):
        return "inf"
    return repr(value)


def write_rig(path: Path, tables: dict[str, dict[str, object]]) -> Path:
    """A rig TOML file of these tables."""
    lines = []
    for table, values in tables.items():
        lines.append(f"[{table}]")
        lines.extend(f"{key} = {_toml_value(v)}" for key, v in values.items())
    path.write_text("\n".join(lines) + "\n")
    return path


def wrong_values(value: object) -> list[object]:
    """Values of the wrong type for a key whose valid value is ``value``."""
    if isinstance(value, bool):
        return ["yes", 1]
    if isinstance(value, (int, float)):
        return ["fast", [1]] if isinstance(value, float) else ["sixty-four", 2.5]
    if isinstance(value, str):
        return [12345]
    if isinstance(value, list):
        return [3, ["a"]]
    raise AssertionError(value)


# (table, key, value) that have the right type but are out of range (bad board sizes are
# test_calib_chessboard's: their messages name the flag and the board)
OUT_OF_RANGE = [
    ("record", "flush_interval_s", -1.0),
    ("record", "queue_size", 0),
    ("record", "min_free_gb", -1.0),
    ("record", "compression", "zip"),
    ("record", "sync_max_offset_s", -0.1),
    ("bench", "fps", 0.0),
    ("bench", "width", -640),
    ("sgbm", "num_disparities", 20),
    ("sgbm", "block_size", 4),
    ("sgbm", "mode", "fast"),
    ("calib", "min_corners", 1),
    ("calib", "capture_views", 0),
    ("calib", "min_views", 0),
    ("train", "epochs", 0),
    ("train", "learning_rate", -1.0),
    ("train", "target", "torque"),
    ("train", "val_fraction", 1.5),
]

# (table, backend, typo'd or foreign key, a wrong-typed known key)
DEVICE_CASES = [
    ("camera", "sim", "widht", None),
    ("camera", "v4l2", "widht", ("width", "640px")),
    ("trocar", "sim", "chanel", None),
    ("trocar", "can", "chanel", ("bitrate", "fast")),
    ("projector", "sim", "width", None),
    ("projector", "hdmi", "width", ("screen", "left")),
    ("projector", "serial", "baud", ("baudrate", "fast")),
]


def _config_command(table: str, rig: Path, corpus: Corpus) -> list[str]:
    """A command that reads ``table`` of the rig config."""
    if table in ("sgbm", "recon"):
        return [
            "reconstruct",
            str(corpus.session),
            "--workers",
            "1",
            "--config",
            str(rig),
            "--out",
            str(fresh(corpus, ".clouds.h5")),
        ]
    if table == "batch":
        return ["verify-sync", str(corpus.session), str(corpus.session), "--config", str(rig)]
    if table == "live":
        return [
            "live",
            "--model",
            str(corpus.model),
            "--calib",
            str(corpus.calibration),
            "--duration",
            "0.2",
            "--headless",
            "--config",
            str(rig),
        ]
    if table == "calib":
        return ["calibrate", "board", str(fresh(corpus, "", "board")), "--config", str(rig)]
    if table == "train":
        return [
            "train",
            str(corpus.session),
            "--out",
            str(fresh(corpus, ".pt")),
            "--config",
            str(rig),
        ]
    return ["record", str(fresh(corpus, ".h5", "rec")), "--duration", "0.2", "--config", str(rig)]


def config_cases(corpus: Corpus) -> list[Case]:
    """Wrong types, unknown keys and out-of-range values for every key of every table."""
    small = read_toml(corpus.rig, "rig config")
    tables = {
        name: values
        for name, values in default_config().items()
        if name not in ("camera", "trocar", "projector")
    }
    cases = []

    def add(name: str, table: str, key: str, change: dict[str, object], must: bool = True) -> None:
        rig = {t: dict(v) for t, v in small.items()}
        rig.setdefault(table, {}).update(change)
        path = write_rig(fresh(corpus, ".toml", "rig"), rig)
        cases.append(Case(name, _config_command(table, path, corpus), (f"[{table}]",), must))
        cases[-1].key = key  # type: ignore[attr-defined]

    for table, values in tables.items():
        for key, value in values.items():
            for wrong in wrong_values(value):
                add(f"[{table}] {key} = {wrong!r}", table, key, {key: wrong})
        add(f"[{table}] unknown key", table, "colour_depth", {"colour_depth": 8})
    for table, key, value in OUT_OF_RANGE:
        add(f"[{table}] {key} = {value!r}", table, key, {key: value})
    for table, backend, typo, wrong in DEVICE_CASES:
        add(f"[{table}] backend {backend}: {typo}", table, typo, {"backend": backend, typo: 1})
        if wrong:
            add(
                f"[{table}] backend {backend}: {wrong[0]} = {wrong[1]!r}",
                table,
                wrong[0],
                {"backend": backend, wrong[0]: wrong[1]},
            )
    return cases


def test_wrong_config_values_and_keys(corpus, capsys):
    cases = config_cases(corpus)
    failures = []
    for case in cases:
        code, err = run_cli(case.argv, capsys)
        problem = judge(case, code, err)
        if problem is None and case.key not in err:  # type: ignore[attr-defined]
            problem = f"error does not name the key {case.key!r}: {err.strip()[-200:]}"  # type: ignore[attr-defined]
        if problem:
            failures.append(f"{case.name}: {problem}")
    with capsys.disabled():
        print(f"\n[mutations] {len(cases)} config cases, {len(failures)} failed")
    assert not failures, f"{len(failures)} of {len(cases)} cases failed:\n" + "\n".join(failures)


# --- a representative subset as real processes ------------------------------------------------
def test_representative_cases_through_subprocesses(corpus):
    """The same outcomes when vbfe runs as its own process (what a user sees)."""
    session = fresh(corpus, ".h5", "sub")
    shutil.copy(corpus.session, session)
    with h5py.File(session, "r+") as f:
        del f["force/force_n"]
    noisy = fresh(corpus, ".h5", "sub")
    data = bytearray(corpus.session.read_bytes())
    data[:4096] = np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    noisy.write_bytes(bytes(data))
    nodes = _storage_nodes(corpus.calibration)
    nan_k1 = nodes["K1"].copy()
    nan_k1[0, 0] = np.nan
    bad_calib = write_storage(fresh(corpus, ".yaml", "sub"), {**nodes, "K1": nan_k1})
    json_calib = fresh(corpus, ".json", "sub")
    json_calib.write_text('{"K1": [1, 2, 3]}')
    rig = write_rig(fresh(corpus, ".toml", "sub"), {"trocar": {"backend": "can", "chanel": 1}})
    afile = fresh(corpus, ".txt", "afile")
    afile.write_text("x")
    cases = [
        (["inspect", str(session)], str(session)),
        (["verify-sync", str(noisy), "--no-store"], str(noisy)),
        (
            ["calibrate", "check", str(bad_calib), "--against", str(corpus.calibration)],
            str(bad_calib),
        ),
        (
            [
                "reconstruct",
                str(corpus.session),
                "--calib",
                str(json_calib),
                "--out",
                str(fresh(corpus, ".clouds.h5")),
            ],
            str(json_calib),
        ),
        (
            [
                "record",
                str(fresh(corpus, ".h5")),
                "--duration",
                "0.2",
                "--calib",
                str(bad_calib),
                "--config",
                str(corpus.rig),
            ],
            str(bad_calib),
        ),
        (["record", str(fresh(corpus, ".h5")), "--config", str(rig)], "chanel"),
        (["inspect", str(corpus.session), "--recover", "/nonexistent/x.h5"], "/nonexistent"),
        (
            [
                "reconstruct",
                str(corpus.session),
                "--calib",
                str(corpus.calibration),
                "--ply-dir",
                str(afile),
                "--out",
                str(fresh(corpus, ".clouds.h5")),
            ],
            str(afile),
        ),
    ]
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen"}
    for argv, name in cases:
        out = subprocess.run(
            [sys.executable, "-m", "vbfe.cli.main", *argv],
            capture_output=True,
            text=True,
            env=env,
            timeout=120,
        )
        lines = [
            line
            for line in out.stderr.replace("\r", "\n").splitlines()
            if ": error:" in line or "Traceback" in line
        ]
        assert out.returncode == 2, (argv, out.stderr[-2000:])
        assert len(lines) == 1 and lines[0].startswith(f"vbfe {argv[0]}: error:"), lines
        assert name in lines[0], lines[0]


# --- output paths ------------------------------------------------------------------------------
def test_output_paths_are_checked_before_work(corpus, capsys):
    afile = fresh(corpus, ".txt", "afile")
    afile.write_text("x")
    missing = corpus.folder / "no" / "such" / "dir"
    clouds = lambda: str(fresh(corpus, ".clouds.h5"))  # noqa: E731
    reconstruct = [
        "reconstruct",
        str(corpus.session),
        "--calib",
        str(corpus.calibration),
        "--workers",
        "1",
        "--config",
        str(corpus.rig),
    ]
    cases = [
        Case(
            "--recover into a missing folder",
            ["inspect", str(corpus.session), "--recover", str(missing / "x.h5")],
            (str(missing),),
        ),
        Case(
            "--recover onto a folder",
            ["inspect", str(corpus.session), "--recover", str(corpus.folder)],
            (str(corpus.folder),),
        ),
        Case(
            "evaluate --out a file",
            ["evaluate", str(corpus.model), str(corpus.session), "--out", str(afile)],
            (str(afile),),
        ),
        Case(
            "reconstruct --ply-dir a file",
            [*reconstruct, "--out", clouds(), "--ply-dir", str(afile)],
            (str(afile),),
        ),
        Case(
            "reconstruct --out in a missing folder",
            [*reconstruct, "--out", str(missing / "c.h5")],
            (str(missing),),
        ),
        Case(
            "reconstruct --out a folder",
            [*reconstruct, "--out", str(corpus.folder)],
            (str(corpus.folder),),
        ),
        Case(
            "train --out in a missing folder",
            [
                "train",
                str(corpus.session),
                "--config",
                str(corpus.rig),
                "--out",
                str(missing / "m.pt"),
            ],
            (str(missing),),
        ),
        Case(
            "train --out a folder",
            [
                "train",
                str(corpus.session),
                "--config",
                str(corpus.rig),
                "--out",
                str(corpus.folder),
            ],
            (str(corpus.folder),),
        ),
        Case(
            "calibrate stereo --out in a missing folder",
            ["calibrate", "stereo", str(corpus.folder), "--out", str(missing / "c.yaml")],
            (str(missing),),
        ),
        Case(
            "record into a folder",
            ["record", str(corpus.folder), "--duration", "0.2", "--config", str(corpus.rig)],
            (str(corpus.folder),),
        ),
    ]
    run_cases(cases, capsys)


def test_training_on_one_session_warns_there_is_no_validation_set(corpus, capsys):
    code, err = run_cli(
        [
            "train",
            str(corpus.session),
            "--config",
            str(corpus.rig),
            "--out",
            str(fresh(corpus, ".pt")),
        ],
        capsys,
    )
    assert code == 0
    assert "warning" in err and "validation" in err and "one session" in err, err[-500:]
