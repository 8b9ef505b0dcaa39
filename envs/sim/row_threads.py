"""Row ranges of a world stage on threads: the helper the compiled (nogil) stages share.

Rows of a world are independent, so a stage whose kernel releases the GIL can run row ranges on several threads
and give the same bits as one call over all rows. The ranges are handed out dynamically (a thread takes the next
range when it is done), so a core that another process keeps busy costs only its share.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from functools import cache
from typing import Callable

import numpy as np

ROWS_PER_TASK = 8
"""Fewest rows per thread task (handing a task over costs tens of microseconds)."""

OVERLAP_ROWS = 16
"""From this many rows on, a world runs two independent parts of its work at once, one of them on a thread of its
own (:func:`envs.sim.world.generate_world`: the IMU beside the GNSS stages; :mod:`envs.sim.trajectory`: the arc
nodes' states beside the node pass): they write separate arrays, or separate elements of one, so the world is the
same either way. Below it, starting the thread costs more than the overlap gains."""


@cache
def _cpus() -> int:
    """``os.cpu_count()``, read once (a call costs ~8 us, and a world of one row asked four times)."""
    return os.cpu_count() or 1


def default_workers(n_rows: int | None = None) -> int:
    """Threads a world stage uses by default: ``min(os.cpu_count(), 8)``, and no more than ``n_rows``."""
    w = max(1, min(_cpus(), 8))
    return w if n_rows is None else max(1, min(w, int(n_rows)))


def run_row_ranges(fn: Callable[[int, int], None], n_rows: int, workers: int | None = None,
                   min_rows: int = ROWS_PER_TASK) -> None:
    """Call ``fn(r0, r1)`` on row ranges that cover ``0 .. n_rows`` once each, on ``workers`` threads.

    Parameters
    ----------
    fn : callable ``(r0, r1) -> None``; it must write only rows ``r0 .. r1-1`` of its outputs (then the result
        does not depend on the split).
    n_rows : number of rows, >= 0.
    workers : threads; None: :func:`default_workers`. 1 (or fewer than ``2 min_rows`` rows): one call, no thread.
    min_rows : fewest rows per range; up to ``4 workers`` ranges are made.
    """
    if workers is None:
        workers = default_workers()
    nchunk = 1 if workers <= 1 or n_rows < 2 * min_rows else min(4 * workers, n_rows // min_rows)
    if nchunk <= 1:
        if n_rows > 0:
            fn(0, n_rows)
        return
    bounds = np.linspace(0, n_rows, nchunk + 1).astype(np.int64)
    with ThreadPoolExecutor(max_workers=workers) as ex:
        for _ in ex.map(lambda c: fn(int(bounds[c]), int(bounds[c + 1])), range(nchunk)):
            pass
