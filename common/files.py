"""Where every output file goes: the checks before a command writes, the atomic write, the
free-space check and the one-writer lock of a session.

An output never replaces an existing file unless the user passed ``--overwrite``, never
replaces one of the command's own inputs (even with ``--overwrite``), and never replaces an
HDF5 session with something else. Each output is written under a temporary name in its folder
(``.NAME.PID.partial``) and renamed into place when complete; a failure removes it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import shutil
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, Literal

from vbfe.common.errors import OutputError, VbfeError

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
PARTIAL_SUFFIX = ".partial"
LOCK_SUFFIX = ".lock"
SESSION_FORMAT = "vbfe-session"  # the format attribute of a session file (acquire's layout)

# Every HDF5 file vbfe writes uses the oldest file format that gives SWMR (crash-safe appends
# with readers open): HDF5 1.10's. Whatever HDF5 the installed h5py bundles, MATLAB, HDFView,
# h5dump, R, Julia and older h5py (HDF5 >= 1.10) open the files.
HDF5_LIBVER = ("v110", "v110")

Writes = Literal["file", "hdf5", "session"]


def is_hdf5(path: str | Path) -> bool:
    """Whether ``path`` is an HDF5 file, by its signature (at offset 0; user blocks aside)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == HDF5_SIGNATURE
    except OSError:
        return False


def create_hdf5(path: str | Path) -> Any:
    """A new HDF5 file (an ``h5py.File``, replacing ``path``) in the portable format
    :data:`HDF5_LIBVER`."""
    import h5py

    return h5py.File(path, "w", libver=HDF5_LIBVER)


def is_session(path: str | Path) -> bool:
    """Whether ``path`` is a vbfe session (HDF5 with the session format attribute)."""
    if not is_hdf5(path):
        return False
    import h5py

    try:
        with h5py.File(path, "r", locking=False) as f:
            return f.attrs.get("format") == SESSION_FORMAT
    except (OSError, ValueError):
        return True  # an HDF5 file too damaged to tell is treated as data to keep


def _same_file(a: Path, b: Path) -> bool:
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return a.absolute() == b.absolute()


def _inside(path: Path, folder: Path) -> bool:
    return (
        folder.is_dir()
        and path.exists()
        and any(p.exists() and os.path.samefile(p, folder) for p in path.parents)
    )


def _refuse_input(path: Path, sources: list[Path]) -> None:
    for source in sources:
        if _same_file(path, source):
            raise OutputError(
                f"output {path} is also an input of this command ({source}); "
                "choose another output name"
            )
        if _inside(path, source):
            raise OutputError(
                f"output {path} already exists in the input folder {source} "
                "(it may be one of the inputs); choose another output name"
            )


def check_outputs(
    outputs: Iterable[str | Path | None],
    inputs: Iterable[str | Path | None] = (),
    overwrite: bool = False,
    directories: Iterable[str | Path | None] = (),
    writes: Writes = "file",
) -> None:
    """Refuse, naming the path: an output that is an input (or an existing file inside an input
    folder), an existing output without ``overwrite``, a session replaced by anything but a
    session (an HDF5 file by anything but HDF5, whatever the suffix), a folder given for a file
    or a file for a folder, or a file whose folder is missing. ``directories`` are output
    folders: they may exist when empty (or with ``overwrite``) and are created by the
    command; ``writes`` says what the command puts in its files."""
    sources = [Path(p) for p in inputs if p is not None]
    for path in (Path(p) for p in directories if p is not None):
        _refuse_input(path, sources)
        if path.exists() and not path.is_dir():
            raise OutputError(f"output folder {path} is a file; choose another folder")
        parent = next((p for p in path.parents if p.exists()), Path("."))
        if not parent.is_dir():
            raise OutputError(f"output folder {path}: {parent} is a file, not a folder")
        if path.is_dir() and any(path.iterdir()) and not overwrite:
            raise OutputError(
                f"output folder {path} is not empty; pass --overwrite to write "
                "into it anyway or choose a new folder"
            )
    for path in (Path(p) for p in outputs if p is not None):
        _refuse_input(path, sources)
        if path.is_dir():
            raise OutputError(f"output {path} is a folder; give a file name")
        if not path.parent.is_dir():
            raise OutputError(
                f"output {path}: folder {path.parent} does not exist; create it first"
            )
        if not path.exists():
            continue
        if not overwrite:
            raise OutputError(
                f"{path} already exists; pass --overwrite to replace it or choose a new name"
            )
        if writes != "session" and is_hdf5(path) and (writes == "file" or is_session(path)):
            raise OutputError(
                f"{path} is {'a session' if is_session(path) else 'an HDF5 file'}"
                f", not the kind of file this command writes; --overwrite does "
                "not replace it: choose another output name"
            )


def partial_path(path: str | Path) -> Path:
    """The temporary name an output is written under until it is complete."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}{PARTIAL_SUFFIX}")


def _umask() -> int:
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    return 0o022  # pragma: no cover - kernels before 4.7


def commit(tmp: Path, path: Path) -> Path:
    """Give ``tmp`` the umask's mode and rename it onto ``path`` (atomic on one file system)."""
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)
    return path


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path`` to write the whole output to; when the block
    ends normally it is renamed onto ``path``, otherwise removed (also on Ctrl-C)."""
    path = Path(path)
    tmp = partial_path(path)
    try:
        yield tmp
        commit(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` through :func:`atomic_path`."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    return Path(path)


def save_figure(fig: Any, path: str | Path, **options: Any) -> Path:
    """``fig.savefig`` (matplotlib) through :func:`atomic_path`, in the format of the suffix."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=Path(path).suffix.lstrip(".").lower() or "png", **options)
    return Path(path)


def require_free_space(folder: str | Path, needed_bytes: int, what: str) -> None:
    """Refuse with one line when the file system of ``folder`` has less than ``needed_bytes``
    free (``what`` names the output)."""
    free = shutil.disk_usage(folder).free
    if free < needed_bytes:
        raise OutputError(
            f"no space for {what}: {free / 1e6:.1f} MB free on {folder}, need "
            f"about {needed_bytes / 1e6:.1f} MB; free space or write elsewhere"
        )


def os_error_text(exc: OSError) -> str:
    """One line for an operating-system error while reading or writing a file."""
    name = exc.filename if exc.filename is not None else ""
    reason = exc.strerror or " ".join(str(exc).split())
    if exc.errno == errno.ENOSPC:
        reason = "no space left on the device; free space or write elsewhere"
    elif exc.errno == errno.EROFS:
        reason = "the file system is read-only; write elsewhere"
    elif exc.errno in (errno.EACCES, errno.EPERM):
        reason = "permission denied; write elsewhere"
    text = f"{name}: {reason}" if name else reason
    return text[:400]


def error_line(exc: BaseException) -> str:
    """What went wrong, in one line, as the CLI prints it."""
    if isinstance(exc, OSError):
        text = os_error_text(exc)
    elif isinstance(exc, VbfeError):
        text = str(exc)
    else:
        text = f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


class WriterLock:
    """The lock one writer of a file holds: an exclusive ``flock`` on ``.NAME.lock`` next to
    it, naming the holder's PID. It survives the HDF5 SWMR mode (which drops HDF5's own
    lock), is freed by the kernel when the process dies, and the lock file is removed on
    release."""

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        self.path = path
        self.lock_path = path.with_name(f".{path.name}{LOCK_SUFFIX}")
        self._fd: int | None = None

    def acquire(self) -> WriterLock:
        """Take the lock or raise :class:`OutputError` naming the process that holds it."""
        while True:
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
                os.close(fd)
                raise OutputError(
                    f"{self.path} is being written by process {holder}; wait "
                    "until it finishes or choose another file"
                ) from None
            try:  # the lock file may have been released and removed meanwhile: lock the new one
                same = os.fstat(fd).st_ino == os.stat(self.lock_path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Remove the lock file and free the lock (idempotent)."""
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.lock_path)
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> WriterLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def stale_locks(folder: str | Path) -> list[tuple[Path, str]]:
    """The files in ``folder`` whose :class:`WriterLock` was left behind by a writer that
    died (killed, power lost) without releasing it: (the file, the dead holder's PID)."""
    stale: list[tuple[Path, str]] = []
    for lock_path in sorted(Path(folder).glob(f".*{LOCK_SUFFIX}")):
        try:
            fd = os.open(lock_path, os.O_RDONLY)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            continue  # held: its writer is alive
        else:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
            name = lock_path.name[1 : -len(LOCK_SUFFIX)]
            stale.append((lock_path.with_name(name), holder))
        finally:
            os.close(fd)
    return stale
