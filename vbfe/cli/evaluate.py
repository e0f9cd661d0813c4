"""`vbfe evaluate`: not yet available."""

from __future__ import annotations

import argparse

from vbfe.errors import VbfeError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `evaluate` subcommand."""
    parser = sub.add_parser("evaluate", help="(not yet available)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Not yet available."""
    raise VbfeError("'evaluate' is not yet available")
