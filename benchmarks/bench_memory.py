"""Memory of the envs as a user holds them: resident set size (RSS) per layout, and what the world caches hold.

Each cell runs in a fresh process: it builds the envs of one layout, resets them, runs one episode of every env
(zero actions, automatic resets: the kernels loaded, the first worlds drawn), reads the process's RSS (``VmRSS`` of
``/proc/self/status``), runs ``--episodes`` more and reads it again, and its peak (``ru_maxrss``). Layouts:

* ``single``: one ``gym.make`` env;
* ``dummy-N``: SB3's ``DummyVecEnv`` of N ``gym.make`` envs (what RL Zoo builds);
* ``vector-B``: the native vector env of B rows (``gym.make_vec(..., vectorization_mode="vector_entry_point")``).

``caches`` is what the world caches hold at the end, each array counted once (views by their base): the env
cores' own bulk arrays (:mod:`envs.sim.buffers`, ``TuningCore.world_buffers``), the prepared worlds of the
batches drawn ahead (:mod:`envs.worlds_ahead`, per env) and the thread's bulk arrays of those batches (one set
per thread). The growth (end minus after the first episode) is what the later episodes added; the rest of the RSS is the
interpreter, numpy, numba's compiled kernels and the envs themselves.

``--compare DIR`` runs every cell in this tree and in the source tree ``DIR`` (e.g. a checkout of an earlier
commit), alternately, and prints both and the ratio of their growths.

Usage: ``python benchmarks/bench_memory.py [--layouts single dummy-16 vector-64] [--episodes 20]
[--episode-s 60] [--scenario noise-burst] [--compare DIR]``.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys

ROOT = os.environ.get("NAVGYM_BENCH_ROOT") or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MB = 2.0 ** 20


def rss_mb() -> float:
    """This process's resident set size [MB] (``VmRSS``; Linux)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024 / MB
    raise RuntimeError("no VmRSS in /proc/self/status (bench_memory needs Linux)")


def _base(a):
    while isinstance(a.base, type(a)):
        a = a.base
    return a


def cache_bytes(cores) -> int:
    """Bytes the world caches of the env ``cores`` hold (each array once, views by their base)."""
    import numpy as np
    seen = {}

    def add(arrays):
        for a in arrays:
            if isinstance(a, np.ndarray):
                b = _base(a)
                seen[id(b)] = b

    try:
        from envs.worlds_ahead import shared_buffers
        add(shared_buffers()._arrays.values())
    except ImportError:  # a tree before the shared bulk arrays (--compare)
        pass
    for core in cores:
        buffers = getattr(core, "world_buffers", None)
        if buffers is not None:
            add(buffers._arrays.values())
        ahead = getattr(core, "worlds_ahead", None)
        if ahead is not None:
            if getattr(ahead, "buffers", None) is not None:  # per env, before the shared arrays
                add(ahead.buffers._arrays.values())
            for part in ahead._parts.values():
                add(part.arrays.values())
    return sum(b.nbytes for b in seen.values())


def run_cell(layout: str, episodes: int, episode_s: float, scenario: str) -> dict:
    """Build the envs of ``layout``, run ``episodes`` episodes of each; returns the cell's figures (MB)."""
    sys.path.insert(0, ROOT)
    import gymnasium as gym
    import numpy as np

    import envs  # noqa: F401
    kw = dict(scenario=scenario, episode_length_s=episode_s)
    kind, _, count = layout.partition("-")
    if kind == "single":
        n, env = 1, gym.make("GnssIns/SageHusa-v1", **kw)
        env.reset(seed=0)
        cores = [env.unwrapped.core]
        action = np.zeros(env.action_space.shape, np.float32)

        def step(a):  # the single env does not reset itself
            if any(env.step(a)[2:4]):
                env.reset()
    elif kind == "dummy":
        from stable_baselines3.common.vec_env import DummyVecEnv
        n = int(count)
        env = DummyVecEnv([lambda: gym.make("GnssIns/SageHusa-v1", **kw) for _ in range(n)])
        env.seed(0)
        env.reset()
        cores = [e.unwrapped.core for e in env.envs]
        step = env.step
        action = np.zeros((n, 1), np.float32)
    elif kind == "vector":
        n = int(count)
        env = gym.make_vec("GnssIns/SageHusa-v1", num_envs=n, vectorization_mode="vector_entry_point", **kw)
        env.reset(seed=0)
        cores = [env.unwrapped.core]
        step = env.step
        action = np.zeros((n, 1), np.float32)
    else:
        raise ValueError(f"unknown layout {layout!r}: single, dummy-N or vector-B")
    M = int(cores[0].M)  # an episode's GNSS epochs, one per step
    for _ in range(M):  # the first episode: the kernels loaded, the first worlds drawn
        step(action)
    first = rss_mb()
    for _ in range(episodes * M):
        step(action)
    end = rss_mb()
    out = dict(layout=layout, rows=n, first=first, end=end, growth=end - first,
               peak=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, caches=cache_bytes(cores) / MB)
    env.close()
    return out


def _cell(root: str, layout: str, a) -> dict:
    """:func:`run_cell` in a fresh process on the source tree ``root``."""
    cmd = [sys.executable, os.path.abspath(__file__), "--cell", layout, "--episodes", str(a.episodes),
           "--episode-s", str(a.episode_s), "--scenario", a.scenario]
    out = subprocess.run(cmd, env=dict(os.environ, NAVGYM_BENCH_ROOT=root), cwd=root, capture_output=True,
                         text=True)
    if out.returncode:
        raise SystemExit(f"bench_memory: the cell {layout} failed in {root}:\n{out.stderr.strip()[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--layouts", nargs="+", default=["single", "dummy-16", "vector-64"],
                   help="single, dummy-N (DummyVecEnv of N single envs), vector-B (the native vector env)")
    p.add_argument("--episodes", type=int, default=20, help="episodes of every env (default 20)")
    p.add_argument("--episode-s", type=float, default=60.0, help="episode length [s] (default 60)")
    p.add_argument("--scenario", default="noise-burst")
    p.add_argument("--compare", metavar="DIR", help="also run every cell in the source tree DIR")
    p.add_argument("--cell", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.episodes < 1 or a.episode_s < 1.0:
        p.error("--episodes must be >= 1 and --episode-s >= 1")
    if a.cell:
        print(json.dumps(run_cell(a.cell, a.episodes, a.episode_s, a.scenario)))
        return 0
    if a.compare and not os.path.isdir(os.path.join(a.compare, "envs")):
        p.error(f"--compare {a.compare}: not a navgym source tree (no envs/ folder)")
    print(f"navgym memory: GnssIns/SageHusa-v1, scenario {a.scenario}, {a.episode_s:g} s episodes, {a.episodes} "
          f"episodes of every env, zero actions; RSS in MB, each cell in a fresh process")
    if a.compare:
        print(f"before: {a.compare}; after: {ROOT}")
        print(f"{'layout':12s} {'rows':>5s} {'after 1 episode':>19s} {'end':>19s} {'growth':>17s} {'caches':>17s} "
              f"{'growth after/before':>20s}")
    else:
        print(f"{'layout':12s} {'rows':>5s} {'1 episode':>12s} {'end':>8s} {'growth':>8s} {'peak':>8s} "
              f"{'caches':>8s}")
    for layout in a.layouts:
        after = _cell(ROOT, layout, a)
        if not a.compare:
            print(f"{layout:12s} {after['rows']:5d} {after['first']:12.0f} {after['end']:8.0f} {after['growth']:8.0f} "
                  f"{after['peak']:8.0f} {after['caches']:8.1f}", flush=True)
            continue
        before = _cell(a.compare, layout, a)
        pair = lambda k, w: f"{before[k]:{w}.0f} -> {after[k]:<{w}.0f}"  # noqa: E731
        ratio = after["growth"] / before["growth"] if before["growth"] > 0 else float("nan")
        print(f"{layout:12s} {after['rows']:5d} {pair('first', 8)} {pair('end', 8)} {pair('growth', 7)} "
              f"{before['caches']:7.1f} -> {after['caches']:<7.1f} {ratio:20.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
