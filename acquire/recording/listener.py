"""What an acquisition hands its records to: the :class:`Listener` base and the :class:`Gap`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from vbfe.acquire.session.layout import CAMERA, FORCE, PROJECTOR
from vbfe.drivers.samples import ForceSample, ProjectorEvent, StereoFrame

if TYPE_CHECKING:
    from vbfe.acquire.recording.acquisition import Acquisition, AcquisitionStats


@dataclass(frozen=True)
class Gap:
    """Records of ``stream`` lost between ``last_seq`` and ``next_seq`` (-1: not known)."""

    stream: str
    reason: str  # one of the session layout's gap reasons
    last_seq: int
    next_seq: int
    t_host_ns: int
    count: int


class Listener:
    """A consumer of an acquisition; override the hooks you need (here they do nothing).

    ``on_start``, ``on_tick`` and ``on_stop`` run in the controlling thread (the one calling
    ``start``, ``run`` and ``stop``); the record hooks run in the acquisition's dispatch thread,
    in the order listeners were added, one batch at a time, and must be quick (hand heavy work
    to a thread of your own, as the live estimator's mailbox does). An exception in a record
    hook stops the acquisition; ``stop`` raises it after every listener's ``on_stop``. A
    listener that cannot go on (e.g. a full disk) calls ``acquisition.halt(reason)``.

    A ``lossy`` listener (a view, the live estimate) gets the newest frame rather than every
    frame: its record hooks run on the acquisition's live dispatch thread, fed by the readers
    directly, so it never waits for the file's writer nor holds it back; frames it did not
    take in time are counted in the acquisition's ``live_skipped``.
    """

    lossy = False  # True: the newest frames only, on a thread apart from the recording

    def on_start(self, acquisition: Acquisition) -> None:
        """The rig is open and about to be read.

        :param acquisition: the acquisition this listener was added to.
        :raises Exception: any failure aborts the start (the rig is closed again).
        """

    def on_records(self, stream: str, records: Sequence[Any]) -> None:
        """A batch of one stream, in arrival order. Here: ``camera`` → :meth:`on_frames`,
        ``force`` → :meth:`on_samples`, ``projector`` → :meth:`on_events`; override (and call
        ``super()``) for the streams of further device kinds.

        :param stream: the stream's name (a session layout stream or a ``[streams]`` key).
        :param records: the stream's records (frames, samples, events or stream samples).
        """
        if stream == CAMERA:
            self.on_frames(records)
        elif stream == FORCE:
            self.on_samples(records)
        elif stream == PROJECTOR:
            self.on_events(records)

    def on_frames(self, frames: Sequence[StereoFrame]) -> None:
        """Stereo frames kept by the acquisition."""

    def on_samples(self, samples: Sequence[ForceSample]) -> None:
        """Force samples kept by the acquisition."""

    def on_events(self, events: Sequence[ProjectorEvent]) -> None:
        """Patterns the projector showed."""

    def on_gap(self, gap: Gap) -> None:
        """Records lost (queue full, device disconnected, a bus error the device reported)."""

    def on_round(self) -> None:
        """After each dispatch round (about every 20 ms at most): periodic work such as flushes."""

    def on_tick(self, acquisition: Acquisition, stats: AcquisitionStats) -> None:
        """Every 50 ms while :meth:`Acquisition.run` runs, in its thread (e.g. to show
        patterns with ``acquisition.show``)."""

    def on_stop(self, acquisition: Acquisition) -> None:
        """Reading has ended and every record was dispatched.

        :param acquisition: the acquisition; ``acquisition.stats.end_reason`` says why it ended
            and ``acquisition.error`` holds a failure of a record hook, if any.
        :raises Exception: raised again by :meth:`Acquisition.stop` once every listener has
            stopped (e.g. a :class:`~vbfe.common.errors.SessionError` when the session could
            not be finalized).
        """
