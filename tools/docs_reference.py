"""The generated reference pages of the manual: every command and option of the real ``vbfe``
argument parser, and every rig-file key of ``vbfe/default_rig.toml`` with its default and
comment. mkdocs calls :func:`on_page_markdown` (``hooks`` in mkdocs.yml) for the pages that
hold a marker; tests/app/test_docs_reference.py checks that nothing is left out."""

from __future__ import annotations

import argparse
import re
import sys
from importlib import resources
from typing import Any

from vbfe.cli.main import build_parser

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

CLI_MARKER = "<!-- generated: cli -->"
RIG_MARKER = "<!-- generated: rig-file -->"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse has no public way to walk its subcommands
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _summaries(parser: argparse.ArgumentParser) -> dict[str, str]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return {a.dest: a.help or "" for a in action._choices_actions}
    return {}


def _escape(text: str) -> str:
    return text.replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def _options(parser: argparse.ArgumentParser) -> list[str]:
    rows = ["| option | what it does |", "|---|---|"]
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if action.option_strings:
            names = ", ".join(action.option_strings)
            if action.nargs != 0:
                names += f" {action.metavar or action.dest.upper()}"
        else:
            names = str(action.metavar or action.dest)
        text = action.help or ""
        if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
            text += f" (one of: {', '.join(map(str, action.choices))})"
        rows.append(f"| `{_escape(names)}` | {_escape(text)} |")
    return rows


def _command(path: str, parser: argparse.ArgumentParser, summary: str, depth: int) -> list[str]:
    out = [f"{'#' * depth} `{path}`", ""]
    description = parser.description or summary
    if description:
        out += [_escape(" ".join(description.split())), ""]
    out += ["```", parser.format_usage().strip(), "```", ""]
    out += [*_options(parser), ""]
    summaries = _summaries(parser)
    for name, sub in _subparsers(parser).items():
        out += _command(f"{path} {name}", sub, summaries.get(name, ""), depth + 1)
    return out


def cli_markdown() -> str:
    """Every ``vbfe`` command, its usage and options, from the parser the CLI runs."""
    parser = build_parser()
    out = _options(parser) + [""]
    summaries = _summaries(parser)
    for name, sub in _subparsers(parser).items():
        out += _command(f"vbfe {name}", sub, summaries.get(name, ""), 2)
    return "\n".join(out)


def cli_options() -> list[tuple[str, str]]:
    """(command, option) of every option of every command: what the reference must name."""
    found: list[tuple[str, str]] = []

    def walk(path: str, parser: argparse.ArgumentParser) -> None:
        for action in parser._actions:
            if not isinstance(action, argparse._HelpAction):  # -h: every command has it
                found.extend((path, option) for option in action.option_strings)
        for name, sub in _subparsers(parser).items():
            walk(f"{path} {name}", sub)

    walk("vbfe", build_parser())
    return found


def _comments(text: str) -> dict[tuple[str, str], str]:
    """The comment of each ``[table] key`` of a TOML file: the text after the value and the
    comment lines that continue it."""
    comments: dict[tuple[str, str], str] = {}
    table, last = "", None
    for line in text.splitlines():
        header = re.match(r"\[([\w.]+)\]", line)
        if header:
            table, last = header[1], None
            continue
        key = re.match(r"(\w+)\s*=", line)
        if key:
            last = (table, key[1])
            comments[last] = line.split("#", 1)[1].strip() if "#" in line else ""
        elif line.startswith(" ") and line.strip().startswith("#") and last is not None:
            comments[last] = (comments[last] + " " + line.strip()[1:].strip()).strip()
        else:
            last = None
    return comments


def _value(value: Any) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_value(v)}" for k, v in value.items()) + "}"
    return str(value)


def rig_markdown() -> str:
    """Every table and key of the default rig file, with its default and comment."""
    text = resources.files("vbfe").joinpath("default_rig.toml").read_text()
    tables = tomllib.loads(text)
    comments = _comments(text)
    out = []
    for table, keys in tables.items():
        out += [f"## `[{table}]`", "", "| key | default | what it sets |", "|---|---|---|"]
        for key, value in keys.items():
            comment = _escape(comments.get((table, key), ""))
            out.append(f"| `{key}` | `{_escape(_value(value))}` | {comment} |")
        out.append("")
    return "\n".join(out)


def on_page_markdown(markdown: str, **_: Any) -> str:
    """mkdocs hook: the generated text in place of its marker."""
    if CLI_MARKER in markdown:
        markdown = markdown.replace(CLI_MARKER, cli_markdown())
    if RIG_MARKER in markdown:
        markdown = markdown.replace(RIG_MARKER, rig_markdown())
    return markdown
