"""Acquisition: the HDF5 session format, the synchronizing recorder, its reader and tools."""
