"""`vbfe demo`: the whole pipeline on the simulated bench, with a report to open in a browser."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from vbfe.cli.common import progress
from vbfe.cli.outputs import add_overwrite_option, check_outputs


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `demo` subcommand."""
    parser = sub.add_parser(
        "demo",
        help="run board → calibration → recording → sync check → reconstruction → "
        "training → evaluation on the simulated bench and write an HTML report",
        description="Runs the whole pipeline on the simulated bench (no hardware needed) and "
        "writes OUT/index.html with every figure next to the bench's ground truth.",
    )
    parser.add_argument("--out", default="vbfe-demo", help="report folder (default: vbfe-demo)")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="small images, fewer trials and epochs (about two minutes)",
    )
    add_overwrite_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the demo with a progress bar per stage and print where the report is."""
    from vbfe.demo import run_demo
    from vbfe.demo_report import checks

    check_outputs([], directories=[args.out], overwrite=args.overwrite)
    bars: list[Any] = []

    def stage(name: str, total: int) -> Callable[[int], None]:
        if bars:
            bars[-1].close()
        bar = progress(total=total, desc=name)
        bars.append(bar)

        def advance(n: int = 1) -> None:
            bar.update(n)

        return advance

    try:
        result = run_demo(args.out, quick=args.quick, stage=stage)
    finally:
        if bars:
            bars[-1].close()
    for what, measured, limit, passed in checks(result.numbers):
        print(f"{'PASS' if passed else 'FAIL'}  {what}: {measured} (limit {limit})")
    print(f"report: {result.report_path}")
    return 0
