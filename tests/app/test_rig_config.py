"""Which rig file commands use (--config, $VBFE_RIG, ./vbfe-rig.toml, the user config folder,
else the simulated bench, said first), `vbfe rig show` / `init`, and a typo refused."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.cli import vbfe_here
from vbfe.common.rig_discovery import find_rig_file


@pytest.fixture
def no_rig(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty working folder, no $VBFE_RIG, a user config folder without a rig file."""
    monkeypatch.delenv("VBFE_RIG", raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_record_without_a_rig_file_says_simulated_bench_first(no_rig: Path, capsys) -> None:
    done = vbfe_here(capsys, "record", "x.h5", "--duration", "0.2")  # the 1 s: the same
    assert done.returncode == 0, done.stderr
    first = done.stdout.splitlines()[0]
    assert first == (
        "simulated bench: no rig file (searched --config, $VBFE_RIG, ./vbfe-rig.toml, "
        f"{no_rig / 'config' / 'vbfe' / 'rig.toml'})"
    )
    shown = vbfe_here(capsys, "inspect", "x.h5")
    assert f"rig       {first}" in shown.stdout.splitlines()


def test_discovery_order(no_rig: Path) -> None:
    user = no_rig / "config" / "vbfe" / "rig.toml"
    user.parent.mkdir(parents=True)
    user.write_text("")
    assert find_rig_file().path == user
    (no_rig / "vbfe-rig.toml").write_text("")
    found = find_rig_file()
    assert (found.path, found.found_by) == (no_rig / "vbfe-rig.toml", "./vbfe-rig.toml")
    env = no_rig / "env.toml"
    env.write_text("")
    os.environ["VBFE_RIG"] = str(env)  # monkeypatch's delenv restores it
    assert find_rig_file().path == env
    assert find_rig_file(user).found_by == "--config"


def test_rig_show_names_the_source_of_each_value(no_rig: Path, capsys, monkeypatch) -> None:
    (no_rig / "vbfe-rig.toml").write_text('[trocar]\nbackend = "sim"\n[record]\nqueue_size = 8\n')
    shown = vbfe_here(capsys, "rig", "show")
    assert shown.returncode == 0, shown.stderr
    lines = shown.stdout.splitlines()
    local = f"{no_rig / 'vbfe-rig.toml'} (./vbfe-rig.toml)"
    found = f"rig file {no_rig / 'vbfe-rig.toml'} (from ./vbfe-rig.toml)"
    assert lines[0] == f"{found}: simulated bench"
    assert any(line.startswith("queue_size = 8 ") and line.endswith(f"# {local}") for line in lines)
    assert any(line.startswith("compression = ") and line.endswith("# default") for line in lines)
    env = no_rig / "env.toml"
    env.write_text("[record]\nqueue_size = 16\n")
    monkeypatch.setenv("VBFE_RIG", str(env))
    lines = vbfe_here(capsys, "rig", "show").stdout.splitlines()
    assert any(line.startswith("queue_size = 16 ") and "($VBFE_RIG)" in line for line in lines)


def test_a_typo_in_the_rig_file_is_one_line_naming_key_and_file(no_rig: Path, capsys) -> None:
    bad = no_rig / "rig.toml"
    bad.write_text('[record]\ncompresion = "lzf"\n')
    done = vbfe_here(capsys, "rig", "show", "--config", str(bad))
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1
    assert "'compresion' in [record]" in done.stderr and str(bad) in done.stderr
    bad.write_text("[record]\nqueue_size = 'many'\n")
    done = vbfe_here(capsys, "record", "x.h5", "--config", str(bad))
    assert done.returncode == 2 and "queue_size = 'many' is not an integer" in done.stderr
    assert not (no_rig / "x.h5").exists()


def test_rig_init_writes_a_rig_file_commands_find_and_never_over_one(no_rig: Path, capsys):
    done = vbfe_here(capsys, "rig", "init")
    assert done.returncode == 0, done.stderr
    text = (no_rig / "vbfe-rig.toml").read_text()
    assert text.startswith("# Rig file written by `vbfe rig init`")
    assert "# same seed: same grasp" in text  # the defaults' comments kept
    assert vbfe_here(capsys, "rig", "show").stdout.startswith(
        f"rig file {no_rig / 'vbfe-rig.toml'} (from ./vbfe-rig.toml)"
    )
    again = vbfe_here(capsys, "rig", "init")
    assert again.returncode == 2 and "pass --overwrite" in again.stderr
    assert (no_rig / "vbfe-rig.toml").read_text() == text


def test_a_changed_configuration_is_checked_again_and_says_where_values_came_from() -> None:
    from vbfe.common.errors import ConfigError
    from vbfe.rig_config import builtin_rig

    rig = builtin_rig({"bench": {"width": 320}})
    assert rig.banner() == "simulated bench: no rig file (the built-in configuration)"
    moved = rig.updated({"record": {"min_free_gb": 0.5}}, "the window")
    assert moved.record.min_free_gb == 0.5 and rig.record.min_free_gb != 0.5  # a copy
    assert moved.tables["bench"]["width"] == 320  # the other values kept
    assert moved.origins[("record", "min_free_gb")] == "the window"
    assert moved.origins[("bench", "width")] == "built in"
    with pytest.raises(ConfigError, match="min_free_gbb"):
        rig.updated({"record": {"min_free_gbb": 1.0}})
    with pytest.raises(ConfigError, match=r"\[bench\]"):  # device tables against the backend
        rig.updated({"bench": {"widht": 320}})
