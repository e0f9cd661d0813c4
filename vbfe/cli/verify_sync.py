"""`vbfe verify-sync`: measure the image/force offset of sessions and judge it."""

from __future__ import annotations

import argparse
from pathlib import Path

from vbfe.acquire.sync.check import FAIL, PASS, SyncLimits, verify_sync
from vbfe.acquire.sync.protocol import ProtocolSettings
from vbfe.cli.batch_options import add_batch_options, batch_settings, run_batch
from vbfe.cli.common import add_config_option, positive, rig_from
from vbfe.cli.outputs import add_overwrite_option, check_outputs
from vbfe.rig_config import settle

EXIT_CODES = {PASS: 0, FAIL: 1}  # anything else (INCONCLUSIVE): 3


def register(sub: argparse._SubParsersAction) -> None:
    """Add the `verify-sync` subcommand."""
    parser = sub.add_parser(
        "verify-sync",
        help="estimate the image-force time offset, clock "
        "drift and drops of sessions; PASS/FAIL against the rig's limits "
        "(exit 0/1; 3: inconclusive, record --protocol sync)",
    )
    parser.add_argument(
        "sessions",
        nargs="+",
        metavar="SESSION.h5|MANIFEST.csv",
        help="sessions, or a manifest CSV written by vbfe dataset",
    )
    parser.add_argument(
        "--plot",
        metavar="PNG",
        default=None,
        help="plot of the offset measurement (default: SESSION.sync.png); with several "
        "sessions, the dataset plot: each session's offset in recording order (default for "
        "a manifest: MANIFEST.sync.png)",
    )
    parser.add_argument(
        "--apply",
        action="store_true",
        help="store the measured offset as a frame-time correction and print "
        "the rig config line that applies it to new sessions",
    )
    parser.add_argument(
        "--no-store",
        action="store_true",
        help="do not write the results into the session (single session)",
    )
    parser.add_argument(
        "--workers",
        type=positive(int),
        default=None,
        help="sessions checked at once (default: one per CPU core)",
    )
    add_batch_options(parser)
    add_overwrite_option(parser)
    add_config_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the report(s); exit code 0 PASS, 1 FAIL (or, over several sessions, a step in
    the offset between two of them), 3 INCONCLUSIVE (the worst of many)."""
    from vbfe.batch.manifest import expand_sessions
    from vbfe.common.errors import BatchError

    rig = rig_from(args)
    limits, settings = SyncLimits.from_record(rig.record), ProtocolSettings.from_record(rig.record)
    sessions = expand_sessions(args.sessions)
    if len(sessions) == 1 and not args.sessions[0].endswith(".csv") and not args.executor:
        plot = args.plot or str(Path(sessions[0]).with_suffix(".sync.png"))
        check_outputs([plot], [sessions[0]], args.overwrite)
        report = verify_sync(
            sessions[0],
            limits,
            plot_path=plot,
            store=not args.no_store,
            apply_correction=args.apply,
            settings=settings,
        )
        print(report.text())
        if args.apply:
            written = settle(
                rig_from(args),
                {"record": {"frame_time_correction_s": round(report.correction_s, 6)}},
            )
            print(
                written.text()
                if written is not None
                else "rig config  no rig file to keep it in (vbfe rig init writes one); add to "
                f"[record] of your rig.toml so new sessions are corrected: "
                f"{report.config_suggestion()}"
            )
        return EXIT_CODES.get(report.verdict, 3)
    if args.no_store:
        raise BatchError(
            "--no-store takes a single session; with several, each result is stored in its "
            "session (the dataset view reads them back)"
        )
    from vbfe.batch.tasks import VerifySyncTask

    plot = args.plot or next(
        (str(Path(s).with_suffix(".sync.png")) for s in args.sessions if s.endswith(".csv")), None
    )
    if plot:
        check_outputs([plot], sessions, args.overwrite)
    executor, address = batch_settings(args, rig.batch)
    task = VerifySyncTask(
        limits=dict(limits.__dict__),
        settings=dict(settings.__dict__),
        apply=args.apply,
        overwrite=args.overwrite,
    )
    outcomes = run_batch(
        task,
        sessions,
        executor,
        args.workers,
        address,
        "verify-sync",
        lambda v: f"{v['verdict']} offset {v['offset_ms']:+.2f} ms ({v['action']})",
    )
    code = max(EXIT_CODES.get(o.value["verdict"], 3) for o in outcomes)
    return max(code, _dataset_view(sessions, limits, plot))


def _dataset_view(sessions: list[Path], limits: SyncLimits, plot: str | None) -> int:
    """Print the offsets in recording order and the steps between sessions, plot them; 1 when
    a step is flagged."""
    from vbfe.acquire.sync.dataset import find_steps, in_recording_order, plot_offsets

    offsets = in_recording_order(sessions)
    steps = find_steps(offsets, limits.max_offset_s)
    print("recording order (offset, 95% CI, verdict):")
    for s in offsets:
        print(
            f"  {s.path.name}: {1e3 * s.offset_s:+.2f} ms ({1e3 * s.ci95_s[0]:+.2f} … "
            f"{1e3 * s.ci95_s[1]:+.2f}) {s.verdict}"
        )
    for step in steps:
        print(step.text())
    if not steps:
        print(f"no step between sessions (none beyond ±{1e3 * limits.max_offset_s:g} ms)")
    if plot:
        plot_offsets(plot, offsets, steps)
        print(f"plot: {plot}")
    return 1 if steps else 0
