"""Acquisition: the HDF5 session format, the synchronizing recorder, its reader and tools."""

from vbfe.acquire.clock import ClockFit, fit_clock
from vbfe.acquire.errors import SessionError
from vbfe.acquire.estimates import EstimateStream
from vbfe.acquire.reader import SessionReader, store_analysis, store_calibration, store_estimates
from vbfe.acquire.record import record_session
from vbfe.acquire.recorder import Recorder, RecorderStats
from vbfe.acquire.writer import SessionWriter, finalize_session, recover_session

__all__ = ["ClockFit", "EstimateStream", "Recorder", "RecorderStats", "SessionError", "SessionReader",
           "SessionWriter", "finalize_session", "fit_clock", "record_session", "recover_session", "store_analysis",
           "store_calibration", "store_estimates"]
