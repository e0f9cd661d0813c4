"""Live force estimation: endoscope frames → reconstruction → force model, at frame rate.

Import the modules (:mod:`.estimator`, :mod:`.run`, :mod:`.viewer`); this package imports
nothing heavy so that the CLI starts fast.
"""
