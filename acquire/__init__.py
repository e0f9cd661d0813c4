"""Acquisition: the HDF5 session format, the synchronizing recorder, its reader and tools."""

from vbfe.acquire.session.clock import ClockFit, fit_clock
from vbfe.acquire.errors import SessionError
from vbfe.acquire.session.estimates import EstimateStream
from vbfe.acquire.session.reader import SessionReader, store_analysis, store_calibration, store_estimates
from vbfe.acquire.recording.record import record_session
from vbfe.acquire.recording.recorder import Recorder, RecorderStats
from vbfe.acquire.session.writer import SessionWriter, finalize_session, recover_session

__all__ = ["ClockFit", "EstimateStream", "Recorder", "RecorderStats", "SessionError", "SessionReader",
           "SessionWriter", "finalize_session", "fit_clock", "record_session", "recover_session", "store_analysis",
           "store_calibration", "store_estimates"]
