"""Throughput of the Gymnasium tuning environments (env steps per second) and where a step's time goes.

One env step = one GNSS epoch = the IMU samples of the epoch (100 at 100 Hz / 1 Hz: compiled
mechanization + covariance accumulation) + one tightly coupled update + feedback + observation.

Prints, in one run:

* env steps/s of the single env (``gym.make``, B = 1) and of the native vector env
  (``gym.make_vec(..., vectorization_mode="vector_entry_point")``) at B = 16, 256, 1024, for the methods
  ``sage-husa``, ``stkf``, ``ma-stkf`` and ``svd-akf`` (the Sage-Husa law around the SVD form). Vector
  figures are row-steps: B x steps / wall time. Reset (world generation + filter construction) is timed
  separately and excluded from the step rate; the timed steps stay inside one episode (no autoreset).
* a profile of the step by stage (wall time per step and share) at B = 1 and at the largest B:
  ``propagate`` (the compiled IMU kernel, :meth:`Navigator.propagate_epoch`), ``innovations``
  (:func:`nav_filters.measurements.gnss_innovations`: ranging, dz, H, R), ``predict`` (the flushed time
  update handed to the form), ``form update`` (the form's ``update``: adaptive law + inner filter),
  ``feedback`` (closed-loop correction of the nominal state), ``dop``, ``observation`` (the env's
  observation frame) and ``env glue`` (the rest of ``TuningCore.step``: actions, parameters, errors,
  rewards, infos, vector-env bookkeeping).

Usage::

    python benchmarks/bench_envs.py [--quick] [--methods sage-husa stkf] [--batches 16 256 1024]
                                    [--steps N] [--episode-s 60] [--no-profile]

``--quick``: B = 1, 16, 256, fewer steps, profile at B = 1 and 256 only (about a minute).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from contextlib import contextmanager

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import envs  # noqa: E402,F401  (registers the ids)
import nav_filters.navigator as navmod  # noqa: E402
from envs import core as coremod  # noqa: E402

METHOD_ENV = {
    "sage-husa": "GnssIns/SageHusa-v0",
    "stkf": "GnssIns/STKF-v0",
    "ma-stkf": "GnssIns/MASTKF-v0",
    "svd-akf": "GnssIns/SageHusa-v0",
}
"""Benchmarked method -> the env id whose action drives it."""

STAGES = ("propagate", "innovations", "predict", "form update", "feedback", "dop", "observation", "env glue")


def _actions(space, n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, size=(n,) + space.shape).astype(np.float32)


def _make(method, B, episode_s, scenario):
    kw = dict(method=method, episode_length_s=float(episode_s), scenario=scenario)
    if B == 1:
        return gym.make(METHOD_ENV[method], **kw)
    return gym.make_vec(METHOD_ENV[method], num_envs=B, vectorization_mode="vector_entry_point", **kw)


def _core(env):
    return env.unwrapped.core if hasattr(env, "unwrapped") and hasattr(env.unwrapped, "core") else env.core


def bench_env(method, B, steps, episode_s, scenario, warmup=2):
    """(reset seconds, steps/s, CPU ms per step) over ``steps`` timed steps after ``warmup`` untimed ones.

    The CPU time (all threads of the process) is the load-robust figure on a shared machine: with other
    jobs on the cores the wall rate drops, the CPU time per step much less."""
    env = _make(method, B, episode_s, scenario)
    if warmup + steps >= episode_s * 1.0:  # 1 Hz GNSS by default: stay inside one episode
        raise ValueError(f"warmup + steps ({warmup + steps}) must stay below the episode length ({episode_s} epochs)")
    t0 = time.perf_counter()
    env.reset(seed=0)
    t_reset = time.perf_counter() - t0
    acts = _actions(env.action_space, warmup + steps)
    for a in acts[:warmup]:
        env.step(a)
    t0, c0 = time.perf_counter(), time.process_time()
    for a in acts[warmup:]:
        env.step(a)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    env.close()
    return t_reset, B * steps / dt, 1e3 * dc / steps


class StageTimer:
    """Accumulates wall time per stage by wrapping the navigator's and the core's step functions."""

    def __init__(self):
        self.t = dict.fromkeys(STAGES, 0.0)
        self._undo = []

    @contextmanager
    def installed(self, core):
        nav = core.nav
        self._wrap(nav, "propagate_epoch", "propagate")
        self._wrap(nav, "flush_prediction", "predict")
        self._wrap(nav.form, "update", "form update")
        self._wrap(nav, "_feedback", "feedback")
        self._wrap(navmod, "gnss_innovations", "innovations")
        self._wrap(navmod, "dop", "dop")
        self._wrap(core, "_frame", "observation")
        try:
            yield self
        finally:
            for obj, name, old, had in reversed(self._undo):
                if had:
                    setattr(obj, name, old)
                else:
                    delattr(obj, name)
            self._undo.clear()

    def _wrap(self, obj, name, stage):
        had = name in vars(obj)
        fn = getattr(obj, name)
        acc = self.t

        def timed(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                acc[stage] += time.perf_counter() - t0

        self._undo.append((obj, name, vars(obj).get(name), had))
        setattr(obj, name, timed)


def profile_env(method, B, steps, episode_s, scenario, warmup=2):
    """Per-stage wall time per step [ms] of ``steps`` steps (after ``warmup``)."""
    env = _make(method, B, episode_s, scenario)
    env.reset(seed=0)
    acts = _actions(env.action_space, warmup + steps)
    for a in acts[:warmup]:
        env.step(a)
    core = _core(env)
    timer = StageTimer()
    with timer.installed(core):
        t0 = time.perf_counter()
        for a in acts[warmup:]:
            env.step(a)
        total = time.perf_counter() - t0
    env.close()
    t = timer.t
    # flush_prediction runs inside Navigator.update, which the form-update timer does not cover; the form's
    # update is called from Navigator.update after it, so the stages do not overlap.
    t["env glue"] = total - sum(v for k, v in t.items() if k != "env glue")
    return {k: 1e3 * v / steps for k, v in t.items()}, 1e3 * total / steps


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="B up to 256, fewer steps")
    p.add_argument("--methods", nargs="+", default=list(METHOD_ENV), choices=list(METHOD_ENV))
    p.add_argument("--batches", nargs="+", type=int, default=None, help="vector batch sizes (default 16 256 1024)")
    p.add_argument("--steps", type=int, default=None, help="timed steps per measurement")
    p.add_argument("--episode-s", type=float, default=60.0, help="episode length [s] (memory: B x IMU samples)")
    p.add_argument("--scenario", default="noise-burst")
    p.add_argument("--no-profile", action="store_true")
    args = p.parse_args(argv)
    batches = args.batches or ([16, 256] if args.quick else [16, 256, 1024])
    print(f"navgym env throughput: scenario {args.scenario}, episode {args.episode_s:g} s, "
          f"{os.cpu_count()} CPUs; one step = one GNSS epoch (100 IMU samples + update)")

    def n_steps(B):
        if args.steps:
            return args.steps
        if args.quick:
            return 20 if B == 1 else 5
        return 40 if B == 1 else (20 if B <= 16 else 8)

    hdr = f"{'method':10s} {'B':>5s} {'reset [s]':>10s} {'steps/s':>12s} {'ms/step':>9s} {'cpu ms/step':>12s}"
    print("\n" + hdr + "\n" + "-" * len(hdr))
    for m in args.methods:
        for B in [1] + batches:
            t_reset, rate, cpu = bench_env(m, B, n_steps(B), args.episode_s, args.scenario)
            print(f"{m:10s} {B:5d} {t_reset:10.2f} {rate:12.0f} {1e3 * B / rate:9.2f} {cpu:12.2f}", flush=True)

    if args.no_profile:
        return
    m = "sage-husa" if "sage-husa" in args.methods else args.methods[0]
    prof_b = [1, max(batches)]
    res = {B: profile_env(m, B, n_steps(B), args.episode_s, args.scenario) for B in prof_b}
    print(f"\nprofile of one step, {m}: ms per step (share)")
    print(f"{'stage':14s}" + "".join(f"{'B=' + str(B):>18s}" for B in prof_b))
    for s in STAGES:
        print(f"{s:14s}" + "".join(f"{res[B][0][s]:10.3f} ({100 * res[B][0][s] / res[B][1]:4.1f}%)" for B in prof_b))
    print(f"{'total':14s}" + "".join(f"{res[B][1]:10.3f}        " for B in prof_b))


if __name__ == "__main__":
    main()
