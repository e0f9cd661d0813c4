"""The HDF5 session format: its layout, the writer, the reader, inspection, verification and
recovery (documented in docs/reference/session-format.md)."""
