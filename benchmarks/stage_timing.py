"""Timing helper shared by the benchmark scripts (stage profiles that wrap the functions they time)."""
from __future__ import annotations

import time


def timed(fn, acc, key, clock=time.perf_counter, counts=None):
    """``fn`` wrapped so that every call adds its elapsed ``clock()`` time [s] to ``acc[key]`` (also when it
    raises), and 1 to ``counts[key]`` when ``counts`` is given: ``clock`` is ``time.perf_counter`` for wall time
    or ``time.process_time`` for the CPU time of all the process's threads."""
    def wrapper(*args, **kwargs):
        t0 = clock()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[key] += clock() - t0
            if counts is not None:
                counts[key] += 1
    return wrapper
