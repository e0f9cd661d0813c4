"""Settled values written back into a rig file: comments kept, a dated backup, nothing
written when refused."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import pytest

from vbfe.common.errors import ConfigError
from vbfe.common.rig_writeback import write_back
from vbfe.rig_config import load_rig

RIG = """\
# the lab's rig (hand-written)
[record]
compression = "lzf"   # keep lzf: mjpeg loses the pattern
frame_time_correction_s = 0.0

[calib]
square_mm = 3.0  # measured with calipers
"""


def test_write_back_keeps_comments_and_a_dated_backup(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    done = write_back(
        rig,
        {"record": {"frame_time_correction_s": 0.037}, "live": {"model": tmp_path / "m.pt"}},
        now=dt.datetime(2026, 12, 6, 4, 15, 2),
    )
    text = rig.read_text()
    assert done.backup == tmp_path / "rig.toml.20261206-041502.bak"
    assert done.backup.read_text() == RIG
    for comment in ("# the lab's rig", "# keep lzf: mjpeg", "# measured with calipers"):
        assert comment in text
    config = load_rig(rig)
    assert config.record.frame_time_correction_s == 0.037
    assert config.live.model == str(tmp_path / "m.pt")
    assert done.changes[0] == ("record", "frame_time_correction_s", 0.0, 0.037)
    assert "(was 0.0)" in done.text() and str(done.backup) in done.text()
    # the same values again: nothing written, no second backup
    again = write_back(rig, {"record": {"frame_time_correction_s": 0.037}})
    assert again.backup is None and again.changes == []
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "rig.toml",
        "rig.toml.20261206-041502.bak",
    ]


def test_a_refused_write_back_leaves_the_file(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)

    def refuse(tables: dict) -> None:
        raise ConfigError(f"[calib] square_mm = {tables['calib']['square_mm']} is out of range")

    with pytest.raises(ConfigError, match="out of range"):
        write_back(rig, {"calib": {"square_mm": -1.0}}, check=refuse)
    with pytest.raises(ConfigError, match="not a TOML value"):
        write_back(rig, {"calib": {"square_mm": object()}})
    assert rig.read_text() == RIG
    assert [p.name for p in tmp_path.iterdir()] == ["rig.toml"]
