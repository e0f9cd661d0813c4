"""The console's calibration and sync work (no Qt): board views captured from the live frames
and calibrated with the calibration commands, the sync protocol session checked and corrected
with ``verify_sync``. Each method that takes long is meant for a worker thread."""

from __future__ import annotations

import threading
from collections import Counter
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from vbfe.acquire.recording.latest import Latest
from vbfe.acquire.sync.check import SyncLimits, SyncReport, verify_sync
from vbfe.acquire.sync.protocol import ProtocolSettings
from vbfe.batch.inputs import check_outputs
from vbfe.calib import CheckResult, commands, load_views, save_views
from vbfe.calib.capture import CaptureOptions, Verdict, ViewCollector, rejection_kind
from vbfe.common.config import default_config
from vbfe.drivers import StereoFrame
from vbfe.rig_config import RigConfig

_IDLE_WAIT_S = 0.02


def save_rig_file(config: RigConfig, path: Path) -> Path:
    """Write ``config`` as a new rig file: the built-in one with its comments, each value
    that ``config`` changes set (an existing file is refused: it is kept as it is)."""
    import tomlkit

    from vbfe.common.files import write_bytes_atomic

    check_outputs([path], [])
    text = resources.files("vbfe").joinpath("default_rig.toml").read_text(encoding="utf-8")
    doc = tomlkit.parse(text)
    defaults = default_config()
    for table, values in config.tables.items():
        for key, value in values.items():
            if defaults.get(table, {}).get(key) != value:
                doc[table][key] = str(value) if isinstance(value, Path) else value
    return write_bytes_atomic(path, tomlkit.dumps(doc))


class LiveCapture:
    """Offer the newest live frames to a :class:`ViewCollector` of the ``[calib]`` board and
    keep the good views in ``folder`` (views already there count, as ``calibrate capture``
    resumes), on a thread of its own between :meth:`start` and :meth:`stop`.

    :param config: the rig config (board and thresholds of its ``[calib]`` table).
    :param folder: where kept views are written as PNG pairs.
    """

    def __init__(self, config: RigConfig, folder: Path) -> None:
        self.folder = Path(folder)
        self.collector = ViewCollector(
            commands.board_spec(config), CaptureOptions.from_config(config.tables["calib"])
        )
        if self.folder.is_dir() and any(self.folder.glob("*_left.png")):
            for left, right in load_views(self.folder).pairs:
                self.collector.keep(left, right)
        self.rejections: Counter[str] = Counter()
        self.last: tuple[Verdict, np.ndarray] | None = None  # newest verdict and its left image
        self.offered = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    @property
    def kept(self) -> int:
        """Views kept so far (those found in the folder included)."""
        return len(self.collector.pairs)

    def offer(self, frame: StereoFrame) -> Verdict:
        """Check one frame; keep and write it when it is a good new view."""
        verdict = self.collector.offer(frame.left, frame.right)
        with self._lock:
            self.offered += 1
            if verdict.kept:
                save_views(self.folder, [(frame.left, frame.right)], [f"view_{self.kept - 1:03d}"])
            else:
                self.rejections[rejection_kind(verdict.reason)] += 1
            self.last = (verdict, frame.left)
        return verdict

    def start(self, latest: Latest) -> None:
        """Offer each new frame of ``latest`` until :meth:`stop` or enough views are kept."""
        self._stop.clear()
        self._thread = threading.Thread(
            target=self._run, args=(latest,), name="vbfe-console-capture", daemon=True
        )
        self._thread.start()

    def running(self) -> bool:
        """Whether frames are being offered."""
        return self._thread is not None and self._thread.is_alive()

    def stop(self) -> None:
        """Stop offering frames."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def _run(self, latest: Latest) -> None:
        seen: StereoFrame | None = None
        while not self._stop.is_set() and not self.collector.enough:
            frame = latest.frame
            if frame is None or frame is seen:
                self._stop.wait(_IDLE_WAIT_S)
                continue
            seen = frame
            self.offer(frame)


@dataclass(frozen=True)
class CalibrationOutcome:
    """A stereo calibration made in the console and, with a stored one, the go/no-go."""

    outcome: commands.StereoOutcome
    check: CheckResult | None

    def per_view_rms_px(self) -> dict[str, float]:
        """Left camera's reprojection RMS of each view used."""
        fit = self.outcome.result.left
        return dict(zip(self.outcome.result.names, map(float, fit.per_view_rms_px), strict=False))

    def view_rows(self) -> list[ViewRow]:
        """Every view of the folder: its reprojection RMS (left, right, stereo) when the
        calibration used it, else why it was left out."""
        result = self.outcome.result
        rms = result.calibration.per_view_rms_px
        used = {
            name: tuple(map(float, rms[k])) if rms is not None else None
            for k, name in enumerate(result.names)
        }
        rows = []
        for name in self.outcome.views.names:
            if name in used:
                rows.append(ViewRow(name, used[name], "used"))
            else:
                why = result.dropped.get(name, "not used by the calibration")
                rows.append(ViewRow(name, None, f"refused: {why}"))
        return rows

    def view_picture(self, name: str) -> np.ndarray:
        """View ``name``'s left and right image side by side with the board corners found in
        each (detected again, as the calibration's detector does)."""
        from vbfe.calib import BoardDetector
        from vbfe.calib.capture import annotate

        views = self.outcome.views
        left, right = views.pairs[views.names.index(name)]
        detector = BoardDetector(self.outcome.spec)
        shown = [annotate(image, detector.detect(image), {}) for image in (left, right)]
        height = max(image.shape[0] for image in shown)
        padded = [np.pad(i, ((0, height - i.shape[0]), (0, 0), (0, 0))) for i in shown]
        return np.hstack(padded)


@dataclass(frozen=True)
class ViewRow:
    """One calibration view: its RMS (left, right, stereo, px) when used, and its status
    (``"used"`` or ``"refused: why"``)."""

    name: str
    rms_px: tuple[float, ...] | None
    status: str


def calibrate(
    config: RigConfig,
    folder: Path,
    out_path: Path,
    stored: Path | None = None,
    overwrite: bool = False,
    swap_eyes: bool = False,
    intrinsics: tuple[Path, Path] | None = None,
) -> CalibrationOutcome:
    """``calibrate stereo`` on a views folder (any layout the CLI takes; ``swap_eyes`` and
    fixed ``intrinsics`` as its options) into ``out_path`` (refused when it exists unless
    ``overwrite``, as the CLI), then ``calibrate check`` of ``stored`` against it."""
    check_outputs([out_path], [folder, stored, *(intrinsics or ())], overwrite)
    outcome = commands.stereo(config, folder, out_path, swap_eyes=swap_eyes, intrinsics=intrinsics)
    check = commands.check(config, stored, new_path=out_path) if stored is not None else None
    return CalibrationOutcome(outcome, check)


@dataclass(frozen=True)
class SyncOutcome:
    """The sync protocol session's check; after :func:`apply_sync` also the run that stored
    the correction (``applied``) and the check with it (``after``)."""

    report: SyncReport
    applied: SyncReport | None = None
    after: SyncReport | None = None

    @property
    def verdict(self) -> str:
        """The latest verdict (after the correction, once applied)."""
        return (self.after or self.report).verdict


def check_sync(config: RigConfig, session: Path) -> SyncOutcome:
    """``verify-sync`` of a sync protocol session (its plot beside it, as the CLI)."""
    report = verify_sync(
        session,
        SyncLimits.from_record(config.record),
        plot_path=session.with_suffix(".sync.png"),
        settings=ProtocolSettings.from_record(config.record),
    )
    return SyncOutcome(report)


def apply_sync(config: RigConfig, checked: SyncOutcome) -> SyncOutcome:
    """``verify-sync --apply`` on the session ``checked``: store the measured offset as its
    frame-time correction (``applied.correction_s``: the ``[record]`` value for new
    recordings); the session is checked again with it."""
    limits = SyncLimits.from_record(config.record)
    settings = ProtocolSettings.from_record(config.record)
    session = checked.report.path
    applied = verify_sync(session, limits, apply_correction=True, settings=settings)
    return SyncOutcome(checked.report, applied, verify_sync(session, limits, settings=settings))
