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


def test_the_benchmark_page_shows_what_a_kept_run_printed(tmp_path, capsys):
    from benchmarks import logbook
    from tools.docs_benchmarks import benchmarks_markdown

    assert logbook.main(["bench_drivers", "--smoke"], runs=tmp_path) == 2  # never kept
    assert logbook.main(["bench_nothing"], runs=tmp_path) == 2
    assert not list(tmp_path.iterdir())
    capsys.readouterr()
    assert logbook.main(["bench_drivers", "--frames", "300"], runs=tmp_path) == 0
    printed = capsys.readouterr().out
    (kept,) = (tmp_path / "bench_drivers").glob("*.json")
    page = benchmarks_markdown(tmp_path)
    scripts = sorted(p.stem for p in (logbook.ROOT / "benchmarks").glob("bench_*.py"))
    assert [line[4:-1] for line in page.splitlines() if line.startswith("## ")] == scripts
    section = page.split("## `bench_drivers`")[1].split("\n## ")[0]
    assert "`python -m benchmarks.bench_drivers --frames 300`" in section
    assert "load average" in section and "cores" in section
    lines = [line for line in printed.splitlines() if line and not line.startswith("kept in")]
    assert lines and all(line in section for line in lines)  # what it printed, as printed
    assert section.count("No kept run yet") == 0 and "No kept run yet" in page
