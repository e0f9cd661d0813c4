"""Remote control in the manner of LabRecorder's RCS: experiment scripts drive recordings over
TCP with LabRecorder's line commands.

One command per line (UTF-8); every command is answered ``OK`` (LabRecorder's reply, no line
end) or ``ERROR <what is wrong>``:

- ``filename {root:/data/study} {template:sub-%p/ses-%s/%b_run-%r.xdf} {participant:P003}
  {session:1} {task:pull} {run:2} {acquisition:…} {modality:…}``: where the next recording
  goes; ``%p %s %b %a %m`` take participant, session, task, acquisition, modality and
  ``%n``/``%r`` the run as three digits (LabRecorder's wildcards); an ``.xdf`` suffix becomes
  ``.h5``; missing folders are made.
- ``start`` / ``stop``: record into that file / stop, finalize, then answer.
- ``update``, ``select all``: accepted (vbfe records the rig and every ``[streams]`` entry,
  resolved at ``start``); ``select none`` is refused.
- ``mark <text>`` (vbfe's own): an event in the running session's event list, at the host time
  the line arrived (what ``vbfe mark`` sends).
"""

from __future__ import annotations

import contextlib
import re
import signal
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from vbfe.acquire.recording.record import check_camera_size, session_recorder
from vbfe.acquire.recording.settings import RecordConfig
from vbfe.acquire.session.extra_streams import marks_stream
from vbfe.common.errors import SessionError, VbfeError
from vbfe.drivers.registry import open_rig

DEFAULT_PORT = 22345  # LabRecorder's RCSPort
DEFAULT_TEMPLATE = "exp%n/block_%b.h5"  # LabRecorder's legacy default
_OPTION = re.compile(r"\{(\w+?):([^}]*)\}")
_FIELDS = {
    "task": "%b",
    "participant": "%p",
    "session": "%s",
    "acquisition": "%a",
    "modality": "%m",
}
_MAX_LINE = 64 * 1024


@dataclass(frozen=True)
class Command:
    """One parsed line: ``verb`` and its argument or ``filename`` options."""

    verb: str
    argument: str = ""
    options: dict[str, str] = field(default_factory=dict)


def parse_command(line: str) -> Command:
    """A command line as LabRecorder reads it; SessionError for anything else."""
    line = line.strip()
    verb, _, rest = line.partition(" ")
    if verb in ("start", "stop", "update") and not rest:
        return Command(verb)
    if verb == "select" and rest.strip() in ("all", "none"):
        return Command(verb, rest.strip())
    if verb == "filename":
        options = {k.lower(): v for k, v in _OPTION.findall(rest)}
        if not options:
            raise SessionError("filename needs options like {root:/data} {template:%p_%b.xdf}")
        unknown = sorted(set(options) - {"root", "template", "run", *_FIELDS})
        if unknown:
            raise SessionError(f"filename: unknown option(s) {unknown}")
        if "run" in options and not options["run"].strip().isdigit():
            raise SessionError(f"filename: run {options['run']!r} is not a number")
        return Command(verb, options=options)
    if verb == "mark" and rest.strip():
        return Command(verb, rest.strip())
    raise SessionError(
        f"unknown command {line[:80]!r}; known: filename, start, stop, update, "
        "select all, mark <text>"
    )


def session_path(options: dict[str, str]) -> Path:
    """The file a ``filename`` command's options name (LabRecorder's wildcards; .xdf → .h5)."""
    path = options.get("template", DEFAULT_TEMPLATE)
    for key, wildcard in _FIELDS.items():
        path = path.replace(wildcard, options.get(key, ""))
    run = f"{int(options.get('run', '1')):03d}"
    path = path.replace("%n", run).replace("%r", run)
    out = Path(options.get("root", ".")).expanduser() / path.strip()
    return out.with_suffix(".h5") if out.suffix.lower() in (".xdf", "") else out


def first_free_run(options: dict[str, str], last_run: int = 999) -> dict[str, str]:
    """``options`` with ``run`` set to the first number (from their ``run``, default 1) whose
    file (:func:`session_path`) does not exist yet, as LabRecorder's running number; a template
    without ``%n``/``%r`` names one file, refused when it exists. SessionError when every run
    up to ``last_run`` is taken."""
    template = options.get("template", DEFAULT_TEMPLATE)
    first = int(options.get("run", "1"))
    runs = range(first, last_run + 1) if "%n" in template or "%r" in template else (first,)
    for run in runs:
        candidate = {**options, "run": str(run)}
        if not session_path(candidate).exists():
            return candidate
    raise SessionError(
        f"{session_path({**options, 'run': str(runs[-1])})} already exists; choose a new file "
        "name (a template with %n numbers the runs)"
    )


class Recording(Protocol):
    """A running recording as remote control needs it."""

    def mark(self, text: str, t_host_ns: int) -> None: ...

    def stop(self, reason: str = ...) -> str: ...  # stop, finalize; a one-line summary


class RemoteRecording:
    """A recording started by remote control: the config's rig recorded into ``path`` (with
    the session's event marks) in a thread of its own until :meth:`stop`; ``options`` go to
    :func:`~vbfe.acquire.recording.record.session_recorder`."""

    def __init__(
        self,
        config: RecordConfig,
        path: Path,
        calibration_size: tuple[int, int] | None = None,
        calibration_name: str = "the calibration",
        **options: Any,
    ) -> None:
        rig = open_rig(config)
        check_camera_size(rig, calibration_size, calibration_name)
        self.recorder = session_recorder(config, path, rig, streams=(marks_stream(),), **options)
        self.error: BaseException | None = None
        self.recorder.start()
        self._thread = threading.Thread(target=self._run, name="vbfe-remote-recording", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self.recorder.run()
        except Exception as exc:  # noqa: BLE001 - reported by stop()
            self.error = exc

    def mark(self, text: str, t_host_ns: int) -> None:
        """An event mark at host time ``t_host_ns``."""
        self.recorder.sink.mark(text, t_host_ns)

    def stop(self, reason: str = "stopped by remote control") -> str:
        """Stop, finalize; a one-line summary (SessionError when the recording failed)."""
        self.recorder.request_stop(reason)
        self._thread.join()
        if self.error is not None:
            raise SessionError(f"recording {self.recorder.path} failed: {self.error}")
        stats = self.recorder.stats
        return (
            f"{self.recorder.path}: {stats.frames} frames, {stats.samples} force samples, "
            f"{stats.elapsed_s:.2f} s, dropped {stats.dropped}; {stats.end_reason}"
        )


class RemoteSessions:
    """The recorder's side of the commands: ``begin(path)`` starts a recording into ``path``
    (a new file; existing ones are refused unless ``overwrite``) and returns it."""

    def __init__(
        self,
        begin: Callable[[Path], Recording],
        overwrite: bool = False,
        on_message: Callable[[str], None] = print,
    ) -> None:
        self._begin, self._overwrite, self._say = begin, overwrite, on_message
        self._options: dict[str, str] = {}
        self._active: tuple[Recording, Path] | None = None  # the recording and its file
        self._lock = threading.Lock()
        self.finished: list[Path] = []

    @property
    def recording(self) -> bool:
        """Whether a recording is running."""
        return self._active is not None

    def handle(self, command: Command, t_host_ns: int) -> None:
        """Carry out one command; SessionError says why it cannot be."""
        with self._lock:
            if command.verb == "filename":
                self._options = {**self._options, **command.options}
                self._say(f"remote: next recording goes to {session_path(self._options)}")
            elif command.verb == "start":
                self._start()
            elif command.verb == "stop":
                if self._active is None:
                    raise SessionError("stop: nothing is being recorded")
                (recording, path), self._active = self._active, None
                self._say(f"remote: {recording.stop()}")
                self.finished.append(path)
            elif command.verb == "mark":
                if self._active is None:
                    raise SessionError("mark: nothing is being recorded")
                self._active[0].mark(command.argument, t_host_ns)
            elif command.verb == "select" and command.argument == "none":
                raise SessionError("select none: vbfe records the rig and every [streams] entry")

    def _start(self) -> None:
        if self._active is not None:
            raise SessionError(f"start: already recording {self._active[1]}; send stop first")
        if not self._options:
            raise SessionError("start: send filename {root:…} {template:…} first")
        path = session_path(self._options)
        if path.exists() and not self._overwrite:
            raise SessionError(
                f"start: {path} already exists; send a new filename (e.g. the next {{run:N}})"
            )
        path.parent.mkdir(parents=True, exist_ok=True)
        self._active = self._begin(path), path
        self._say(f"remote: recording {path}")

    def close(self, reason: str = "stopped by operator") -> None:
        """Stop a recording still running (the server is going away)."""
        with self._lock:
            if self._active is not None:
                (recording, path), self._active = self._active, None
                self._say(f"remote: {recording.stop(reason)}")
                self.finished.append(path)


class RemoteControl:
    """A TCP server that reads command lines from any number of clients and hands them to
    ``sessions``; bound to ``bind`` (localhost unless told otherwise)."""

    def __init__(
        self, sessions: RemoteSessions, port: int = DEFAULT_PORT, bind: str = "127.0.0.1"
    ) -> None:
        self.sessions = sessions
        try:
            self._server = socket.create_server((bind, port), reuse_port=False)
        except OSError as exc:
            raise SessionError(
                f"cannot listen for remote control on {bind}:{port}: {exc.strerror or exc}"
            ) from None
        self.port = self._server.getsockname()[1]
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._accept, name="vbfe-remote", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                client, _ = self._server.accept()
            except OSError:
                return
            threading.Thread(
                target=self._serve, args=(client,), name="vbfe-remote-client", daemon=True
            ).start()

    def _serve(self, client: socket.socket) -> None:
        with client, client.makefile("rb") as lines:
            for raw in lines:
                t_host_ns = time.monotonic_ns()
                if len(raw) > _MAX_LINE:
                    reply = "ERROR line too long"
                else:
                    try:
                        self.sessions.handle(
                            parse_command(raw.decode("utf-8", "replace")), t_host_ns
                        )
                        reply = "OK"
                    except VbfeError as exc:  # bad command, missing device, full disk, …
                        reply = f"ERROR {exc}"
                try:
                    client.sendall(reply.encode())
                except OSError:
                    return

    def close(self) -> None:
        """Stop listening (a running recording is stopped by ``sessions.close()``)."""
        self._closed.set()
        with contextlib.suppress(OSError):
            self._server.shutdown(socket.SHUT_RDWR)  # wakes the thread blocked in accept()
        self._server.close()
        self._thread.join()


def serve(server: RemoteControl, on_ready: Callable[[int], None]) -> None:
    """Serve until Ctrl-C or SIGTERM (``on_ready(port)`` once listening), then stop a
    recording still running (finalized) and the server."""

    def stop(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        on_ready(server.port)
        while True:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        server.close()
        server.sessions.close()


def send_command(
    line: str, port: int = DEFAULT_PORT, host: str = "127.0.0.1", timeout_s: float = 60.0
) -> str:
    """Send one command line to a remote-control port and return its reply."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as sock:
            sock.sendall(line.encode() + b"\n")
            return sock.recv(4096).decode("utf-8", "replace")
    except OSError as exc:
        raise SessionError(
            f"no recorder answers on {host}:{port} ({exc.strerror or exc}); "
            f"start one with `vbfe record --remote {port}`"
        ) from None
