"""Acquisition: the HDF5 session format, the acquisition and its listeners, the reader and tools."""

from vbfe.acquire.recording.acquisition import Acquisition, AcquisitionStats
from vbfe.acquire.recording.frame_feed import FrameFeed, frame_feed
from vbfe.acquire.recording.listener import Gap, Listener
from vbfe.acquire.recording.record import record_session
from vbfe.acquire.recording.recorder import Recorder
from vbfe.acquire.recording.session_sink import SessionSink
from vbfe.acquire.session.annotate import store_analysis, store_calibration, store_estimates
from vbfe.acquire.session.clock import ClockFit, fit_clock
from vbfe.acquire.session.estimates import EstimateStream
from vbfe.acquire.session.layout import Column, StreamSpec
from vbfe.acquire.session.reader import SessionReader
from vbfe.acquire.session.recovery import recover_session
from vbfe.acquire.session.writer import SessionWriter, finalize_session
from vbfe.common.errors import SessionError

__all__ = [
    "Acquisition",
    "AcquisitionStats",
    "ClockFit",
    "Column",
    "EstimateStream",
    "FrameFeed",
    "Gap",
    "Listener",
    "Recorder",
    "SessionError",
    "SessionReader",
    "SessionSink",
    "SessionWriter",
    "StreamSpec",
    "finalize_session",
    "fit_clock",
    "frame_feed",
    "record_session",
    "recover_session",
    "store_analysis",
    "store_calibration",
    "store_estimates",
]
