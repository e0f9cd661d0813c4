"""Recording: the acquisition (device reader threads, dispatch to listeners), the session sink,
the record command's rig setup, the ``[record]`` settings and the sync protocol session."""
