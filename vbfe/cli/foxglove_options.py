"""``--foxglove [PORT]`` and ``--images`` of `vbfe live` and `vbfe record`."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from vbfe.live.foxglove_server import FoxgloveServer

DEFAULT_PORT = 8765  # Foxglove's own default


def add_foxglove_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--foxglove [PORT]`` and ``--images``."""
    parser.add_argument(
        "--foxglove",
        nargs="?",
        type=int,
        const=DEFAULT_PORT,
        default=None,
        metavar="PORT",
        help=f"serve the rig live to Foxglove on ws://127.0.0.1:PORT (default {DEFAULT_PORT}; "
        "0: a free port): images, trocar wrench, projector events, extra streams, estimates "
        "and clouds (vbfe live); frames are skipped for the viewer, never for the recording "
        "(docs/how-to/foxglove.md)",
    )
    parser.add_argument(
        "--images",
        default=None,
        metavar="png|jpeg[:QUALITY]|raw",
        help="how --foxglove sends images: jpeg:90 (default), png (lossless), raw",
    )


def foxglove_server(args: argparse.Namespace, target: str = "") -> FoxgloveServer | None:
    """The server ``--foxglove`` asks for, listening already (None without it), printing its
    address once the rig runs; LiveError for a bad or busy port, BagError for a bad
    ``--images``."""
    from vbfe.common.errors import LiveError
    from vbfe.live.foxglove_server import LIVE_IMAGES, FoxgloveServer
    from vbfe.messages.images import image_codec

    if args.foxglove is None:
        if args.images is not None:
            raise LiveError("--images applies to --foxglove; add --foxglove [PORT]")
        return None
    if not 0 <= args.foxglove < 65536:
        raise LiveError(f"--foxglove {args.foxglove}: give a TCP port 1-65535 (0: any free one)")
    images = image_codec(args.images) if args.images is not None else LIVE_IMAGES
    server = FoxgloveServer(
        args.foxglove,
        images,
        target=target,
        on_ready=lambda url: print(
            f"Foxglove: open {url} (docs/how-to/foxglove.md)", file=sys.stderr, flush=True
        ),
    )
    server.open()  # a busy port is refused before anything is recorded
    return server
