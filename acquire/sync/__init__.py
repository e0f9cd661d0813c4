"""Sync analysis of recorded sessions: image-vs-force offsets from force corners, change
signals and the sync protocol's flashes and taps, judged against the ``[record]`` limits."""
