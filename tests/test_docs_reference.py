"""The manual's generated reference (tools/docs_reference.py, built by mkdocs in .ci/run):
every option of every command is in it with a help text, every rig-file table and key too."""

from __future__ import annotations

from tools.docs_reference import cli_markdown, cli_options, rig_markdown
from vbfe.common.config import default_config


def test_every_cli_option_is_in_the_reference_with_what_it_does():
    page = cli_markdown()
    options = cli_options()
    assert len({command for command, _ in options}) >= 20  # every command and action walked
    missing = [(c, o) for c, o in options if f"`{o}" not in page and f", {o}" not in page]
    assert not missing, f"options missing from docs/reference/cli.md: {missing}"
    undocumented = [
        row for row in page.splitlines() if row.startswith("| `") and row.endswith("|  |")
    ]
    assert not undocumented, f"options without a help text: {undocumented}"


def test_every_rig_file_key_is_in_the_reference():
    page = rig_markdown()
    for table, keys in default_config().items():
        assert f"## `[{table}]`" in page
        for key in keys:
            assert f"| `{key}` |" in page, f"[{table}] {key}"
