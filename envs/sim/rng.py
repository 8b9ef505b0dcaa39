"""Per-row random streams: what makes batching change nothing but speed.

Row ``i`` of every batched simulation draws its random numbers only from the
generators built here from ``seeds[i]``, one independent stream per component
(trajectory, IMU, GNSS, initial errors). The draws of a row therefore do not
depend on the batch size or on the other rows: B = 1 with seed s equals row i
of B = 64 whose seeds[i] = s.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

STREAMS = {"trajectory": 1, "imu": 2, "gnss": 3, "init": 4, "events": 5, "vibration": 6, "odometer": 101}
"""Fixed stream ids: adding a component never shifts another component's draws (``odometer``: 101, the id
the seed003 experiment drew its odometer from before the odometer became part of the world)."""


def as_seeds(seeds) -> list[int]:
    """Normalize an int or a sequence of non-negative ints to a list; ``ValueError`` otherwise."""
    if isinstance(seeds, (int, np.integer)):
        seeds = [int(seeds)]
    out = []
    for i, s in enumerate(seeds):
        if not isinstance(s, (int, np.integer)) or s < 0:
            raise ValueError(f"seeds[{i}] must be a non-negative int, got {s!r}")
        out.append(int(s))
    if not out:
        raise ValueError("seeds must not be empty")
    return out


def row_generators(seeds: Sequence[int], stream: str) -> list[np.random.Generator]:
    """One ``numpy.random.Generator`` per batch row for the named stream.

    Parameters
    ----------
    seeds : sequence of B non-negative ints (one per row).
    stream : a key of :data:`STREAMS`.

    Returns
    -------
    list of B generators; row i depends only on (seeds[i], stream).
    """
    if stream not in STREAMS:
        raise ValueError(f"unknown random stream {stream!r}; known: {sorted(STREAMS)}")
    return [np.random.default_rng(np.random.SeedSequence(s, spawn_key=(STREAMS[stream],))) for s in as_seeds(seeds)]
