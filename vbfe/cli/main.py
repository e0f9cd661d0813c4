"""The ``vbfe`` command: parses arguments, hands work to the packages, prints one-line errors."""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Sequence

from vbfe.cli import (
    calibrate,
    dataset,
    demo,
    devices,
    evaluate,
    export,
    import_data,
    inspect,
    live,
    mark,
    reconstruct,
    record,
    report,
    rig,
    train,
    upgrade,
    verify_sync,
    view,
)
from vbfe.cli import (
    console as console_command,
)
from vbfe.cli.common import rig_from
from vbfe.common import logs
from vbfe.common.errors import (
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    EXIT_TERMINATED,
    ConfigError,
    VbfeError,
)
from vbfe.common.files import os_error_text
from vbfe.common.signals import Terminated, sigterm_as_interrupt
from vbfe.common.version import __version__

COMMANDS = (
    devices,
    rig,
    record,
    mark,
    view,
    inspect,
    upgrade,
    report,
    verify_sync,
    calibrate,
    dataset,
    reconstruct,
    import_data,
    export,
    train,
    evaluate,
    live,
    console_command,
    demo,
)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="vbfe",
        description="Vision-based force estimation: record, calibrate, reconstruct, "
        "train and evaluate with a structured-light stereo endoscope and a force trocar.",
    )
    parser.add_argument("--version", action="version", version=f"vbfe {__version__}")
    _add_log_options(parser, None)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    for command in _parsers(sub):  # `vbfe record -v` as well as `vbfe -v record`
        _add_log_options(command, argparse.SUPPRESS)
    return parser


def _parsers(sub: argparse._SubParsersAction) -> list[argparse.ArgumentParser]:
    """Every parser under ``sub``: the subcommands and their own actions."""
    found = []
    for parser in dict.fromkeys(sub.choices.values()):
        found.append(parser)
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                found += _parsers(action)
    return found


def _add_log_options(parser: argparse.ArgumentParser, default: object) -> None:
    """``-v``/``-q``/``--log-file``; below the top level ``default`` is SUPPRESS, so a
    subcommand's parser keeps what the top level parsed unless given again."""
    group = parser.add_argument_group("logging")
    group.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0 if default is None else default,
        help="log what the library does on stderr (-v information, -vv debug)",
    )
    group.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=False if default is None else default,
        help="log only errors on stderr (not warnings)",
    )
    group.add_argument(
        "--log-file",
        metavar="FILE",
        default=default,
        help="append the log (information and above; debug with -vv) to FILE",
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code (2: bad input or a
    file that cannot be read or written; 130: Ctrl-C; 143: SIGTERM, but for the commands that
    end on them as on their duration, ``record`` and ``live``, which exit 0)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        logs.configure(-1 if args.quiet else args.verbose, args.log_file)
        with sigterm_as_interrupt():
            if hasattr(args, "config"):  # the command uses the rig: say which, first
                print(rig_from(args).banner(), flush=True)
            return int(args.func(args) or 0)
    except VbfeError as exc:
        message = str(exc)
        config = getattr(args, "config", None)
        if isinstance(exc, ConfigError) and config and config not in message:
            message += f" (rig config {config})"
        message = " ".join(line.strip() for line in message.splitlines())  # one line
        print(f"vbfe {args.command}: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        print(f"vbfe {args.command}: error: {os_error_text(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        print(
            f"vbfe {args.command}: error: not enough memory; use smaller inputs or settings",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    except Terminated:
        print(f"vbfe {args.command}: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        print(f"vbfe {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def console() -> None:
    """The `vbfe` console script: run the command, then exit with its status. A Ctrl-C or
    SIGTERM that arrives once the command is done (while Python tears down) is ignored, so
    it cannot turn a finished, finalized command into a death by signal."""
    code = main()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    sys.exit(code)


if __name__ == "__main__":
    console()
