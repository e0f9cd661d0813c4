"""Audit of one stream's sequence numbers: dropped, duplicated and out-of-order samples."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class StreamAudit:
    """What a stream's sequence numbers say about its completeness."""

    stored: int
    expected: int  # last seq - first seq + 1
    dropped: int  # missing sequence numbers (device, transport or queue losses)
    duplicated: int  # repeated sequence numbers
    reordered: int  # steps backwards
    gaps: list[tuple[int, int]] = field(default_factory=list)  # (last seq, next seq)

    @property
    def drop_fraction(self) -> float:
        """Dropped samples over samples the device produced in the recorded span."""
        return self.dropped / self.expected if self.expected else 0.0


def audit_sequence(seq: np.ndarray, max_gaps: int = 100) -> StreamAudit:
    """Count drops, duplicates and reorderings in a stream's recorded sequence numbers."""
    seq = np.asarray(seq, dtype=np.int64)
    if len(seq) == 0:
        return StreamAudit(0, 0, 0, 0, 0)
    step = np.diff(seq)
    jumps = np.flatnonzero(step > 1)
    unique = np.unique(seq)
    expected = int(seq.max() - seq.min() + 1)
    return StreamAudit(
        stored=len(seq),
        expected=expected,
        dropped=expected - len(unique),
        duplicated=len(seq) - len(unique),
        reordered=int((step < 0).sum()),
        gaps=[(int(seq[i]), int(seq[i + 1])) for i in jumps[:max_gaps]],
    )
