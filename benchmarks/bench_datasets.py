"""Build time of a recorded-data world from its spec: first (parsing RINEX with georinex) vs cached.

    .venv/bin/python benchmarks/bench_datasets.py [SPEC_OR_NAME ...]   # default: instinct-reach-static

Each figure is one world build of 4 rows in a fresh in-process state: "first" with an empty on-disk cache
(a temporary folder), "cached" after the in-process memo is cleared (as a new process would find it),
"in-process" with the memo warm (environment resets).
"""
import os
import sys
import tempfile
import time

from envs.datasets import dataset_world
from envs.worlds import make_world


def main(names):
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["NAVGYM_CACHE_DIR"] = tmp
        for name in names:
            dataset_world._prepare_rinex_cached.cache_clear()
            times = []
            for clear in (False, True, False):
                if clear:
                    dataset_world._prepare_rinex_cached.cache_clear()
                    dataset_world._fit_cached.cache_clear()
                t0 = time.perf_counter()
                make_world(name, [0, 1, 2, 3])
                times.append(time.perf_counter() - t0)
            print(f"{name}: first {times[0]:.2f} s, cached {times[1]:.2f} s, in-process {times[2]:.3f} s "
                  f"(first/cached {times[0] / times[1]:.0f}x)")


if __name__ == "__main__":
    main(sys.argv[1:] or ["instinct-reach-static"])
