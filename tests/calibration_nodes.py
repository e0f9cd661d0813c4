"""The nodes of a calibration file as the tests read the format (written here, not taken from
the code under test)."""

# the stereo pair's matrices: every calibration file has them
STEREO_MATRICES = ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q")
