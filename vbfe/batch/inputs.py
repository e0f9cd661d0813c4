"""The one check every command (and the console) runs on its outputs before doing any work (see
:func:`vbfe.common.files.check_outputs`).

The inputs a command names are expanded to everything it reads: the sessions a manifest lists
and the ``X.clouds.h5`` sidecar of every session, so none of them can be an output.
"""

from __future__ import annotations

import glob
from collections.abc import Iterable
from pathlib import Path

from vbfe.common.files import Writes
from vbfe.common.files import check_outputs as _check


def command_inputs(inputs: Iterable[str | Path | None], sidecars: bool = True) -> list[Path]:
    """Every file the inputs stand for: themselves (or the files a glob matches), the sessions
    of manifests (``*.csv`` with a ``path`` column) and (with ``sidecars``) the clouds sidecar
    of every session."""
    # imported here: every command imports this module, few name a manifest or a session
    from vbfe.batch.manifest import MANIFEST_SUFFIX, read_manifest
    from vbfe.common.errors import BatchError
    from vbfe.recon import sidecar_path

    out: list[Path] = []
    for item in (Path(p) for p in inputs if p is not None):
        if not item.exists() and glob.has_magic(str(item)):  # a quoted glob of images
            out.extend(Path(p) for p in glob.glob(str(item)))
        out.append(item)
        listed: list[Path] = []
        if item.suffix == MANIFEST_SUFFIX and item.is_file():
            try:
                listed = read_manifest(item)
            except BatchError:  # another kind of CSV (forces, frame times)
                pass
        for path in (item, *listed):
            if path is not item:
                out.append(path)
            if (
                sidecars
                and path.suffix.lower() in (".h5", ".hdf5")
                and not path.name.endswith(".clouds.h5")
            ):
                out.append(sidecar_path(path))
    return out


def check_outputs(
    outputs: Iterable[str | Path | None],
    inputs: Iterable[str | Path | None] = (),
    overwrite: bool = False,
    directories: Iterable[str | Path | None] = (),
    writes: Writes = "file",
    sidecars: bool = True,
) -> None:
    """:func:`vbfe.common.files.check_outputs` against everything the inputs stand for (without the
    sessions' sidecars when ``sidecars`` is false: a command that writes them)."""
    _check(outputs, command_inputs(inputs, sidecars), overwrite, directories, writes)
