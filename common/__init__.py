"""The basement every layer stands on: the rig config and its typed tables (``config``,
``settings``), the error base class (``errors``), the one output policy and atomic writes
(``files``), signal handling (``signals``) and the one HTML page writer (``report``). It imports
nothing of the pipeline; the pipeline packages and, above them, the CLI, demo, live, batch and
truth import it."""
