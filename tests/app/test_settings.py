"""One settings mechanism: every config table checked the same way, and the calibration writer."""

import base64
import json
import subprocess
import sys

import numpy as np
import pytest

from vbfe.calib.calibration import Calibration
from vbfe.common.errors import ConfigError
from vbfe.common.settings import parse_kwargs, parse_table, setting
from vbfe.drivers.sim.rig import default_rig
from vbfe.truth import calibration_from_rig

# (table, command reading it, an unknown key, a wrong-typed known key)
TABLES = [
    (
        "record",
        ["record", "{tmp}/s.h5", "--duration", "0.1"],
        "compresion",
        ("flush_interval_s", '"one"'),
    ),
    ("bench", ["record", "{tmp}/s.h5", "--duration", "0.1"], "colour", ("fps", '"fast"')),
    (
        "sgbm",
        ["reconstruct", "{tmp}/none.h5"],
        "num_disparity",
        ("num_disparities", '"sixty-four"'),
    ),
    ("calib", ["calibrate", "board", "{tmp}/board"], "sqares_x", ("squares_x", '"9"')),
    ("train", ["train", "{tmp}/none.h5", "--out", "{tmp}/m.pt"], "epoch", ("epochs", "2.5")),
    ("camera", ["record", "{tmp}/s.h5", "--duration", "0.1"], "widht", None),
    ("trocar", ["record", "{tmp}/s.h5", "--duration", "0.1"], "chanel", None),
    ("projector", ["record", "{tmp}/s.h5", "--duration", "0.1"], "width", None),
]


def _run(tmp_path, command, toml):
    rig = tmp_path / "rig.toml"
    rig.write_text(toml)
    argv = [a.format(tmp=tmp_path) for a in command] + ["--config", str(rig)]
    return subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", *argv], capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize("table, command, unknown, wrong", TABLES, ids=[t[0] for t in TABLES])
def test_unknown_key_and_wrong_type_in_each_table(tmp_path, table, command, unknown, wrong):
    cases = [(f"[{table}]\n{unknown} = 1\n", unknown)]
    if wrong:
        cases.append((f"[{table}]\n{wrong[0]} = {wrong[1]}\n", wrong[0]))
    for toml, key in cases:
        out = _run(tmp_path, command, toml)
        assert out.returncode == 2, out.stderr
        lines = [line for line in out.stderr.replace("\r", "\n").splitlines() if line.strip()]
        error = [line for line in lines if ": error:" in line]
        assert len(error) == 1 and error[0].startswith(f"vbfe {command[0]}: error:"), lines
        assert f"[{table}]" in error[0] and repr(key) in error[0] or f"{key} =" in error[0]
        assert "Traceback" not in out.stderr
        assert not (tmp_path / "s.h5").exists()  # nothing started


def test_train_refuses_a_bad_train_key_before_loading_torch(tmp_path):
    (tmp_path / "rig.toml").write_text("[train]\nepochz = 3\n")
    out = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "vbfe.cli.main", "train"]
        + [str(tmp_path / "none.h5"), "--out", str(tmp_path / "m.pt")]
        + ["--config", str(tmp_path / "rig.toml")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2, out.stderr
    imported = [line.split("|")[-1].strip() for line in out.stderr.splitlines() if "|" in line]
    assert "vbfe.rig_config" in imported  # the config was read (its [train] keys listed) ...
    assert "torch" not in imported  # ... without torch
    said = [line for line in out.stderr.splitlines() if not line.startswith("import time:")]
    assert len(said) == 1, said
    assert said[0].startswith(
        f"vbfe train: error: rig config {tmp_path / 'rig.toml'} (from --config): unknown key "
        "'epochz' in [train]; known:"
    )
    assert "epochs" in said[0] and not (tmp_path / "m.pt").exists()


def test_device_keys_are_checked_against_the_backend_before_constructing(tmp_path):
    out = _run(
        tmp_path,
        ["record", "{tmp}/s.h5", "--duration", "0.1"],
        '[trocar]\nbackend = "can"\nchanel = "can0"\n',
    )
    assert out.returncode == 2
    assert "unknown key 'chanel' in [trocar] (backend can); known:" in out.stderr
    assert "channel" in out.stderr and "host_clock" not in out.stderr  # only TOML-able keys


def test_types_ranges_and_choices():
    from dataclasses import dataclass
    from typing import Literal

    @dataclass
    class Table:
        n: int = setting(3, ge=1)
        rate: float = setting(1.0, gt=0)
        mode: Literal["a", "b"] = "a"
        sizes: list[int] = setting([1, 2])
        on: bool = True

    assert parse_table(Table, {"rate": 2, "sizes": [4]}, "t") == Table(rate=2.0, sizes=[4])
    for table, message in (
        ({"n": 0}, r"\[t\] n = 0 is out of range: it must be >= 1"),
        ({"n": True}, r"\[t\] n = True is not an integer"),
        ({"rate": "fast"}, r"\[t\] rate = 'fast' is not a number"),
        ({"mode": "c"}, r"\[t\] mode = 'c' is not one of 'a', 'b'"),
        ({"sizes": [1.5]}, r"\[t\] sizes = \[1.5\] is not a list of integers"),
        ({"on": "yes"}, r"\[t\] on = 'yes' is not true or false"),
        ({"nn": 1}, r"unknown key 'nn' in \[t\]; known: mode, n, on, rate"),
    ):
        with pytest.raises(ConfigError, match=message):
            parse_table(Table, table, "t")

    def backend(port: str, baud: int = 9600, clock=None, *, timeout_s: float | None = None):
        return port

    assert parse_kwargs(backend, {"port": "x", "timeout_s": 1}, "p") == {
        "port": "x",
        "timeout_s": 1.0,
    }
    with pytest.raises(ConfigError, match=r"\[p\] baud = '9600' is not an integer"):
        parse_kwargs(backend, {"baud": "9600"}, "p")


# --- the calibration writer ------------------------------------------------------------------
def _triggering_info(pad: int) -> dict:
    """Info whose JSON, cut in 1000-character pieces, has a piece starting and ending with '"'
    (the old writer's failure: OpenCV writes such a piece verbatim) for some ``pad``."""
    return {"pad": "x" * pad, "rejected_corners": [f'"{i}"' for i in range(400)]}


def test_calibration_with_quote_delimited_info_pieces_round_trips(tmp_path):
    calibration = calibration_from_rig(default_rig(320, 180))
    triggered = 0
    for pad in range(12):
        info = _triggering_info(pad)
        text = json.dumps(info, sort_keys=True)
        pieces = [text[i : i + 1000] for i in range(0, len(text), 1000)]
        triggered += any(p[0] == p[-1] == '"' for p in pieces)
        path = calibration.replace(info=info).save(tmp_path / f"c{pad}.yaml")
        back = Calibration.load(path)
        assert back.info == info
        np.testing.assert_array_equal(back.K1, calibration.K1)
    assert triggered  # the old piece-wise JSON would have hit the bug for this content


def test_calibration_files_of_the_older_raw_json_info_still_load(tmp_path):
    calibration = calibration_from_rig(default_rig(320, 180)).replace(info={"views": ["a"]})
    text = calibration.to_yaml_text()
    start = text.index("info:")
    old = text[:start] + 'info_json:\n   - "{\\"views\\": [\\"a\\"]}"\n'
    assert Calibration.from_yaml_text(old).info == {"views": ["a"]}
    b64 = base64.b64encode(b'{"views": ["a"]}').decode()
    older = text[:start] + f'info_json_base64:\n   - "{b64}"\n'
    assert Calibration.from_yaml_text(older).info == {"views": ["a"]}
