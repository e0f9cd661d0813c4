"""``vbfe console``: one window for the lab operator (rig, live, record, calibrate, sync,
review). :mod:`~vbfe.console.station` and :mod:`~vbfe.console.desks` are the model (no Qt);
the window and its tabs are thin views over them."""

TAB_NAMES = ("Rig", "Live", "Record", "Calibrate", "Sync", "Review")
