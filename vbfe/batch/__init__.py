"""Datasets of many sessions: the manifest (:mod:`.manifest`), one task per session on a local
pool or a Ray cluster (:mod:`.executors`), and the tasks (:mod:`.tasks`). Import the modules;
this package imports nothing heavy so that the CLI starts fast."""
