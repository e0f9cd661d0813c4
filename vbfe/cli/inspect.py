"""`vbfe inspect`: summarize a session file (counts, drops, gaps, clocks; truncated or not)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vbfe.acquire import recover_session
from vbfe.acquire.session.inspect import inspect_session
from vbfe.acquire.session.verify import verify_session
from vbfe.cli.outputs import add_overwrite_option, check_outputs

QUICK_VERIFY_BYTES = 256 << 20  # sessions up to this size are checksummed by every inspect


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `inspect` subcommand."""
    parser = sub.add_parser("inspect", help="summarize a recorded session or a cloud file")
    parser.add_argument(
        "session",
        metavar="SESSION.h5",
        help="a session, or a SESSION.clouds.h5 file (per-frame quality)",
    )
    parser.add_argument(
        "--recover",
        metavar="OUT.h5",
        default=None,
        help="copy an interrupted session into a clean, finalized file",
    )
    parser.add_argument(
        "--verify",
        action="store_true",
        help="read every chunk and report those whose checksum fails (done "
        f"anyway for sessions up to {QUICK_VERIFY_BYTES >> 20} MB)",
    )
    add_overwrite_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the summary; exit code 1 when the file was not closed cleanly or is damaged."""
    from vbfe.recon.clouds import is_cloud_file

    if is_cloud_file(args.session):
        return _inspect_clouds(args.session)
    if args.recover:
        check_outputs([args.recover], [args.session], args.overwrite, writes="session")
        _, dropped = recover_session(args.session, args.recover, overwrite=args.overwrite)
        lost = ", ".join(f"{n} {stream}" for stream, n in dropped.items() if n) or "none"
        print(
            f"recovered {args.session} into {args.recover}; rows dropped for inconsistent "
            f"timestamps: {lost}"
        )
        args.session = args.recover
    damaged = False
    if args.verify or Path(args.session).stat().st_size <= QUICK_VERIFY_BYTES:
        chunks, damage = verify_session(args.session)
        for item in damage:
            print(item.text())
        print(f"verify    {chunks} chunks read, {len(damage)} damaged")
        damaged = bool(damage)
    summary = inspect_session(args.session)
    print(summary.text())
    return 1 if summary.truncated or damaged else 0


def _inspect_clouds(path: str) -> int:
    """Summary line and per-frame quality of a cloud file."""
    from vbfe.recon import CloudReader
    from vbfe.recon.quality import frame_lines, summary_line

    with CloudReader(path) as clouds:
        print(summary_line(clouds))
        print(
            f"  source: {clouds.session_path} ({clouds.attrs.get('source_kind', 'session')}), "
            f"verify: {bool(clouds.attrs.get('verify'))}"
        )
        print("\n".join(frame_lines(clouds)))
    return 0
