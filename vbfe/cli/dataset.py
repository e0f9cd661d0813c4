"""`vbfe dataset`: the sessions under a folder, one row each, and their manifest CSV."""

from __future__ import annotations

import argparse
from pathlib import Path

from vbfe.cli.common import add_config_option, progress, rig_from
from vbfe.cli.outputs import add_overwrite_option, check_outputs

SHOWN = (
    ("path", 28),
    ("status", 10),
    ("condition", 44),
    ("operator", 8),
    ("date_utc", 19),
    ("duration_s", 8),
    ("frames", 6),
    ("frame_drops", 5),
    ("force_drops", 5),
    ("sync_verdict", 6),
    ("calibration_hash", 12),
    ("clouds", 10),
)


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `dataset` subcommand."""
    parser = sub.add_parser(
        "dataset",
        help="list the sessions under a folder; write a manifest",
        description="One row per session below DIR: condition, operator, date, duration, "
        "frames, drops, sync verdict, calibration hash, clouds (missing, stale, current). "
        "With --manifest the rows go to a CSV that train, evaluate, reconstruct and "
        "verify-sync accept instead of a list of session files.",
    )
    parser.add_argument("folder", metavar="DIR", help="folder searched for sessions")
    parser.add_argument(
        "--manifest",
        metavar="FILE.csv",
        default=None,
        help="write the rows to this CSV (paths relative to its folder)",
    )
    parser.add_argument(
        "--report",
        nargs="?",
        const="",
        default=None,
        metavar="FOLDER",
        help="write an HTML page over the sessions, linking a page per session, "
        "into FOLDER (default DIR/report)",
    )
    add_overwrite_option(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def _cell(value: object, width: int) -> str:
    text = str(value)
    return text if len(text) <= width else text[: width - 1] + "…"


def run(args: argparse.Namespace) -> int:
    """Print the table (and write the manifest); exit 1 when a session is unreadable."""
    from vbfe.batch.manifest import scan_dataset, write_manifest
    from vbfe.common.errors import BatchError

    manifest = Path(args.manifest) if args.manifest else None
    if manifest is not None and manifest.suffix != ".csv":
        raise BatchError(f"manifest {manifest} must end in .csv")
    report = None if args.report is None else Path(args.report or Path(args.folder) / "report")
    check_outputs([manifest], overwrite=args.overwrite, directories=[report])
    params = rig_from(args).sgbm
    entries = scan_dataset(
        args.folder, params, relative_to=manifest.parent if manifest else args.folder
    )
    print("  ".join(f"{name:<{width}}" for name, width in SHOWN))
    for entry in entries:
        print(
            "  ".join(
                f"{_cell(getattr(entry, name), width):<{width}}" for name, width in SHOWN
            ).rstrip()
        )
    unreadable = [e for e in entries if e.status.startswith("unreadable")]
    print(
        f"{len(entries)} sessions, {sum(e.clouds == 'current' for e in entries)} with current "
        f"clouds, {len(unreadable)} unreadable"
    )
    if manifest is not None:
        print(f"manifest written to {write_manifest(manifest, entries)}")
    if report is not None:
        from vbfe.batch.dataset_report import write_dataset_report

        with progress(total=len(entries), desc="report", unit="session") as bar:
            index = write_dataset_report(
                args.folder,
                entries,
                report,
                manifest.parent if manifest else None,
                lambda done, total: bar.update(done - bar.n),
            )
        print(f"report written to {index}")
    return 1 if unreadable else 0
