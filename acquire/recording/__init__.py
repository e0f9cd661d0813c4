"""Recording: device reader threads, the writer thread, the record command's rig setup, the
``[record]`` settings and the sync protocol session."""
