"""The `vbfe` command line: every subcommand the operators need is there."""

import subprocess
import sys

import pytest

from vbfe.cli.main import build_parser, main
from vbfe.common.errors import ConfigError
from vbfe.rig_config import load_rig

SUBCOMMANDS = [
    "devices",
    "record",
    "view",
    "inspect",
    "report",
    "verify-sync",
    "calibrate",
    "reconstruct",
    "import",
    "export",
    "train",
    "evaluate",
    "demo",
]


def test_help_lists_every_subcommand():
    text = build_parser().format_help()
    for name in SUBCOMMANDS:
        assert name in text


def test_console_script_runs():
    out = subprocess.run(
        [sys.executable, "-m", "vbfe.cli.main", "--version"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert out.stdout.startswith("vbfe ")


def test_unknown_config_table_is_named(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text("[camra]\nbackend='v4l2'\n")
    with pytest.raises(ConfigError, match="camra"):
        load_rig(rig)


def test_bad_config_is_a_one_line_error_with_exit_status_2(tmp_path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_text("[camera\n")
    assert main(["record", str(tmp_path / "s.h5"), "--duration", "1", "--config", str(rig)]) == 2
    err = capsys.readouterr().err
    assert "not valid TOML" in err and str(rig) in err and "Traceback" not in err
