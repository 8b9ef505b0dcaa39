"""Throughput of the Gymnasium tuning environments (env steps per second) and where a step's time goes.

One env step = one GNSS epoch = the IMU samples of the epoch (100 at 100 Hz / 1 Hz: compiled
mechanization + covariance accumulation) + one tightly coupled update + feedback + observation.

Prints, in one run:

* the headline: **end to end** env-steps/s, what a training loop pays (:func:`bench_end_to_end`: zero actions,
  ``k M + 5`` steps for M epochs per episode, so k automatic resets fall inside the timed steps, each drawing
  its rows' new worlds, k = 2 from B = 20 on and 40 at B = 1 (:func:`e2e_episodes`), after the first episode
  untimed; no prefetch process; at B = 1 the env draws the worlds of its coming resets in batches of 16, as in
  any long loop, :mod:`envs.worlds_ahead`: the first 16 episodes untimed while the batches grow, the timed resets
  pay for the batches, the last one's unused worlds included), beside the step-only figure of the same cell and
  the resets' share of the end-to-end time, at B = 1 and 1024 (``--e2e-batches``), in the env default (fused) mode; and
  what the CPU allows: the resets' share of the CPU time, the cores busy on average, and the bound of
  :func:`cpu_bound` (the e2e rate if that CPU work kept every usable core busy);
* env steps/s of the single env (``gym.make``, B = 1) and of the native vector env
  (``gym.make_vec(..., vectorization_mode="vector_entry_point")``) at B = 16, 256, 1024, for the methods
  ``sage-husa``, ``stkf``, ``ma-stkf`` and ``svd-akf`` (the Sage-Husa law around the SVD form; ``--methods satellite-r
satellite-sage-husa``: the per-satellite envs, ``kf`` and ``sage-husa`` with one action per channel). Vector
  figures are row-steps: B x steps / wall time. Reset (world generation + filter construction) is timed
  separately and excluded from the step rate; the timed steps stay inside one episode (no autoreset).
  ``cpu ms/step`` is the process CPU time (all threads) per batched step: on a shared machine the wall
  rate drops with the other jobs, the CPU time much less.
* a profile of the step by stage (wall time per step and share) at B = 1 and at the largest B:
  ``propagate`` (the compiled IMU kernel, :meth:`Navigator.propagate_epoch`), ``innovations``
  (:func:`nav_filters.measurements.gnss_innovations`: ranging, dz, H, R), ``predict`` (the flushed time
  update handed to the form; an adaptive law only stores it), ``form update`` (the form's ``update``:
  adaptive law + inner filter, including the deferred prediction), ``feedback`` (closed-loop correction
  of the nominal state), ``dop``, ``observation`` (the env's observation frame) and ``env glue`` (the
  rest of ``TuningCore.step`` and the env wrappers: actions, parameters, errors, rewards, infos).

Each method runs in the modes of ``--transitions``: ``exact`` (``exact_transition=True, fused_update=False``:
the per-sample transitions composed in the IMU kernel, the reference eval.py runs and the envs' default before
issue 11), ``averaged`` (``exact_transition=False, fused_update=False``: the epoch's averaged error dynamics,
:mod:`nav_filters.averaged_transition`) and ``fused`` (``exact_transition=False, fused_update=True``, the
default of every env id: also the fused compiled predict + Joseph update, :func:`nav_filters.forms.kf.fused_update`,
and the adaptive laws' fast kernels), rows ``sage-husa``, ``sage-husa avg`` and ``sage-husa fused``.
``--cpu-profile`` gives the stage profile in process CPU time (all threads) instead of wall time: on a
machine shared with other jobs the wall time of a stage swings with their load, its CPU time much less.

``--compare DIR`` runs every cell twice, in this tree and in the source tree ``DIR`` (e.g. a checkout of
an earlier commit), alternately in fresh processes, and prints both with the speed-up: before/after
figures measured side by side under the same machine load. The *before* cell runs the same transition mode
as the *after* cell; where the earlier tree does not have that mode (its env rejects the argument) it falls
back to the exact transition, and the row is marked ``*`` ("before: the exact default of DIR, after: the
mode of this tree"). The stage profile's *before* column is the first mode of ``--transitions`` alike.
``--rounds N`` runs each throughput cell N times in each tree, alternately, and prints the medians and the range
of the N per-round speed-ups: on a shared machine whose speed swings between runs a minute apart, one pair of
cells can show 0.7x or 1.1x for unchanged code. Without ``--compare``, ``--rounds N`` runs each throughput cell
N times in fresh processes, one method and batch after another in turn, and prints the median steps/s with the
lowest and highest of the N (a verdict against a target, e.g. 30k steps/s at B = 1024, is the median's, with
the range beside it).

``--kernel-time`` prints instead, for the first of ``--methods`` in its env default (fused) at B = 1 and 1024 (or
``--batches``), how much of a step runs inside navgym's compiled kernels, per kernel, and how much is the Python
around them (:mod:`kernel_time`).

``--accuracy`` prints instead the accuracy table of the fast modes (averaged, fused) against the exact one on
every built-in scenario, paired episodes (:mod:`transition_accuracy`, a few minutes); ``--filterpy`` the
side-by-side figure against filterpy's plain ``KalmanFilter`` loop (:mod:`filterpy_baseline`): filterpy
epochs/s against navgym row-epochs/s, both per CPU second (per core), in one run.

Usage::

    python benchmarks/bench_envs.py [--quick] [--methods sage-husa stkf] [--batches 1 16 256 1024]
                                    [--steps N] [--episode-s 60] [--no-profile] [--profile-only]
                                    [--transitions exact averaged] [--compare DIR [--rounds N]]
    python benchmarks/bench_envs.py --accuracy [--accuracy-episodes 24] [--accuracy-max-s 700]
                                    [--accuracy-scenarios urban ...] [--accuracy-nees-runs 20]
    python benchmarks/bench_envs.py --filterpy [--batches 1 1024]
    python benchmarks/bench_envs.py --kernel-time [--methods sage-husa] [--batches 1 1024]

``--quick``: B = 1, 16, 256, fewer steps, profile at B = 1 and 256 (a minute or two). ``--headline-only``: only
the end-to-end headline (with ``--compare`` and ``--rounds`` as the throughput table).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from contextlib import contextmanager

ROOT = os.environ.get("NAVGYM_BENCH_ROOT") or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from stage_timing import timed  # noqa: E402  (this script's folder)

import envs  # noqa: E402,F401  (registers the ids)
import nav_filters.navigator as navmod  # noqa: E402

METHOD_ENV = {
    "sage-husa": "GnssIns/SageHusa-v1",
    "stkf": "GnssIns/STKF-v1",
    "ma-stkf": "GnssIns/MASTKF-v1",
    "svd-akf": "GnssIns/SageHusa-v1",
    "satellite-r": "GnssIns/SatelliteR-v0",
    "satellite-sage-husa": "GnssIns/SatelliteSageHusa-v0",
}
"""Benchmarked method -> the env id whose action drives it."""
SATELLITE_METHODS = {"satellite-r": "kf", "satellite-sage-husa": "sage-husa"}
"""The per-satellite envs (one action per channel, :mod:`envs.satellite_env`) under their default filter method
(``--methods satellite-r satellite-sage-husa``; not in the default list, which an earlier tree of ``--compare`` must
also have)."""
DEFAULT_METHODS = [m for m in METHOD_ENV if m not in SATELLITE_METHODS]

WARMUP_STEPS = 12
"""Untimed steps before timing: past the adaptive laws' warm-up (10 epochs) so that every code path (and
every compiled kernel, loaded from numba's cache on first use) has run once."""

STAGES = ("propagate", "innovations", "predict", "epoch inputs", "form update", "feedback", "dop", "observation",
          "env glue")


def _actions(space, n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, size=(n,) + space.shape).astype(np.float32)


TRANSITIONS = ("exact", "averaged", "fused")
"""Modes: ``exact_transition=True, fused_update=False`` (``exact``: the reference, the default of eval.py and of the
envs before issue 11), ``exact_transition=False, fused_update=False`` (``averaged``) and ``exact_transition=False,
fused_update=True`` (``fused``: also the fused compiled predict + Joseph update and the parallel law kernels; the
envs' default)."""

_SHORT = {"exact": "", "averaged": " avg", "fused": " fused"}
NAME_W = max(len(m) for m in METHOD_ENV) + max(len(v) for v in _SHORT.values()) + 1
"""Width of the tables' method column (the longest method name with its mode suffix)."""


def _label(method, transition):
    return method + _SHORT[transition]


def _make(method, B, episode_s, scenario, transition="exact", **env_kwargs):
    """The env of a cell (``env_kwargs``: more arguments, e.g. the vector env's ``parallel_kernels``)."""
    from envs.config import EnvConfig
    kw = dict(method=SATELLITE_METHODS.get(method, method), episode_length_s=float(episode_s), scenario=scenario,
              **env_kwargs)
    fields = EnvConfig.__dataclass_fields__  # an earlier tree (--compare) may lack the arguments (exact only)
    for name, value in (("exact_transition", transition == "exact"), ("fused_update", transition == "fused")):
        if name in fields:
            kw[name] = value  # explicit: the env default is the fused mode since issue 11
        elif value != (name == "exact_transition"):
            raise ValueError(f"this tree's envs have no {name} argument: no {transition!r} mode")
    if B == 1:
        return gym.make(METHOD_ENV[method], **kw)
    return gym.make_vec(METHOD_ENV[method], num_envs=B, vectorization_mode="vector_entry_point", **kw)


def _core(env):
    return env.unwrapped.core if hasattr(env, "unwrapped") and hasattr(env.unwrapped, "core") else env.core


def bench_env(method, B, steps, episode_s, scenario, transition="exact", warmup=WARMUP_STEPS, stat="mean",
              env_kwargs=None, before_close=None):
    """(reset seconds, steps/s, CPU ms per batched step) over ``steps`` timed steps after ``warmup`` ones.

    ``stat``: ``'mean'`` (steps/s from the total wall time) or ``'median'`` (from the median wall time of one
    step: robust to the load spikes of other jobs on a shared machine). ``env_kwargs``: more env arguments;
    ``before_close(env)`` is called after the timed steps (to read the env's state)."""
    if warmup + steps >= episode_s:  # 1 Hz GNSS in every benchmarked scenario: stay inside one episode
        raise ValueError(f"warmup + steps ({warmup + steps}) must stay below the episode length ({episode_s} epochs)")
    env = _make(method, B, episode_s, scenario, transition, **(env_kwargs or {}))
    t0 = time.perf_counter()
    env.reset(seed=0)
    t_reset = time.perf_counter() - t0
    acts = _actions(env.action_space, warmup + steps)
    for a in acts[:warmup]:
        env.step(a)
    t0, c0 = time.perf_counter(), time.process_time()
    ts = []
    for a in acts[warmup:]:
        t1 = time.perf_counter()
        env.step(a)
        ts.append(time.perf_counter() - t1)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    if before_close is not None:
        before_close(env)
    env.close()
    rate = B / float(np.median(ts)) if stat == "median" else B * steps / dt
    return t_reset, rate, 1e3 * dc / steps


E2E_MIN_ROW_EPISODES = 40
"""Fewest row-episodes (B x episodes) one end-to-end cell times. At B = 1 two episodes take ~0.1 s, where one pause
halves the figure. Seen: a process's first automatic reset took 70 ms instead of 10 (55 ms of it inside an
``isinstance`` check against an ABC, in one process of several); the B = 1 cells then read 740-1090 env-steps/s
against 2200-2500. Over 40 episodes such a pause is a few percent, as in a long run."""


def e2e_episodes(B: int) -> int:
    """Episodes an end-to-end cell times at B rows: 2, or enough for :data:`E2E_MIN_ROW_EPISODES` row-episodes."""
    return max(2, -(-E2E_MIN_ROW_EPISODES // B))


def e2e_warmup_episodes(B: int) -> int:
    """Untimed episodes before an end-to-end cell's timed steps: 1 (numba loads its kernels from the cache over the
    first), and 16 where the env draws the worlds of coming resets in batches (fewer than
    ``envs.worlds_ahead.AHEAD_ROWS // 2`` rows): the batches grow over the first 16 resets of a stream (1, 1, 2, 4,
    8 resets' worlds) and the first draws of more rows load more kernels, a process's one-time cost (measured at
    B = 1: 28 ms for the first batch of 2 rows, 10-16 ms later)."""
    try:
        from envs.worlds_ahead import AHEAD_ROWS
    except ImportError:  # pragma: no cover - a source tree before it (--compare): the same warm-up, for a fair pair
        AHEAD_ROWS = 16
    return 16 if 2 * B <= AHEAD_ROWS else 1


E2E_WARMUP_STEPS = 3
"""Untimed steps of :func:`bench_end_to_end` after the first reset where the caller gives ``steps``; else the whole
first episode is untimed: numba loads each compiled kernel from its cache at its first use, over the first
episode (measured at B = 1: 17 loads, that episode at 354 env-steps/s, the next ones at 2200-2700)."""


def bench_end_to_end(method, B, episode_s, scenario, transition="fused", steps=None, env_kwargs=None,
                     before_close=None):
    """End-to-end env-steps/s as a training loop pays it: resets included, no prefetch.

    After ``reset(seed=0)`` and the first episode untimed (M steps for M epochs per episode and the reset that
    follows; the first 16 at B < 8, :func:`e2e_warmup_episodes`; :data:`E2E_WARMUP_STEPS` with ``steps`` given),
    ``steps`` steps with zero actions are timed (default ``k M + 5``, k = :func:`e2e_episodes`: k automatic resets
    fall inside, each drawing its rows' new worlds; the single env, B = 1, is reset by the loop when its episode
    ends, as a user's loop does).
    ``env_kwargs``: more env arguments; ``before_close(env)`` is called after the timed steps.

    Returns (env-steps/s = B x steps / wall time, the resets' share of that time, CPU ms per batched step, the
    resets' share of that CPU time); CPU time is the process's, all threads (``time.process_time``).
    """
    env = _make(method, B, episode_s, scenario, transition, **(env_kwargs or {}))
    env.reset(seed=0)
    core = _core(env)
    M = core.M
    n = steps or e2e_episodes(B) * M + 5
    zero = np.zeros(env.action_space.shape, np.float32)

    def run(k):  # k zero-action steps; the single env is reset by the loop, the vector env resets itself
        for _ in range(k):
            out = env.step(zero)
            if B == 1 and (out[2] or out[3]):
                env.reset()

    run(E2E_WARMUP_STEPS if steps else e2e_warmup_episodes(B) * M)
    acc = {"reset": 0.0, "reset_cpu": 0.0}
    # an instance attribute: the core's own reset, in wall and in CPU time
    core.reset_rows = timed(timed(core.reset_rows, acc, "reset"), acc, "reset_cpu", clock=time.process_time)
    t0, c0 = time.perf_counter(), time.process_time()
    run(n)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    if before_close is not None:
        before_close(env)
    env.close()
    return B * n / dt, acc["reset"] / dt, 1e3 * dc / n, acc["reset_cpu"] / dc


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask where the OS has one, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def cpu_bound(B: int, cpu_ms_per_step: float, cpus: int) -> float:
    """Env-steps/s if the same CPU work per batched step (``cpu_ms_per_step`` [ms], all threads) kept all ``cpus``
    busy all the time: ``cpus x B / CPU seconds per step``, the most any scheduling of that work can reach here."""
    return cpus * B * 1e3 / cpu_ms_per_step


class StageTimer:
    """Accumulates time per stage by wrapping the navigator's and the core's step functions (``clock``:
    ``time.perf_counter`` for wall time, ``time.process_time`` for the CPU time of all the process's threads)."""

    def __init__(self, clock=time.perf_counter):
        self.t = dict.fromkeys(STAGES, 0.0)
        self.clock = clock
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
        # the navigator's compiled GNSS epoch (Navigator._direct_gnss_epoch): one kernel for its inputs (the
        # innovations, keys, averaged transition, preparation and prior together), the law's compiled epoch
        # (the form update), and the feedback, which then also restarts time_since_update and forms the GDOP
        if hasattr(navmod, "_gnss_epoch_inputs"):  # (an older tree of --compare has none)
            self._wrap(navmod, "_gnss_epoch_inputs", "epoch inputs")
        if hasattr(nav.form, "direct_epoch"):
            self._wrap(nav.form, "direct_epoch", "form update")
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
        self._undo.append((obj, name, vars(obj).get(name), had))
        setattr(obj, name, timed(getattr(obj, name), self.t, stage, self.clock))


def profile_env(method, B, steps, episode_s, scenario, transition="exact", warmup=WARMUP_STEPS, cpu=False):
    """Per-stage time per step [ms] of ``steps`` steps (after ``warmup``), and the total: wall time, or with
    ``cpu`` the process CPU time (all threads; robust to other jobs on a shared machine)."""
    env = _make(method, B, episode_s, scenario, transition)
    env.reset(seed=0)
    acts = _actions(env.action_space, warmup + steps)
    for a in acts[:warmup]:
        env.step(a)
    core = _core(env)
    clock = time.process_time if cpu else time.perf_counter
    timer = StageTimer(clock)
    with timer.installed(core):
        t0 = clock()
        for a in acts[warmup:]:
            env.step(a)
        total = clock() - t0
    env.close()
    t = timer.t
    # the stages do not nest: flush_prediction, form.update and _feedback run one after the other inside
    # Navigator.update; gnss_innovations and dop before and after it (or, on the compiled GNSS epoch,
    # _gnss_epoch_inputs, form.direct_epoch and _feedback one after the other).
    t["env glue"] = total - sum(v for k, v in t.items() if k != "env glue")
    return {k: 1e3 * v / steps for k, v in t.items()}, 1e3 * total / steps


def bench_components(batches=(1, 1024), repeats=None):
    """Each compiled kernel of the step against its numpy reference, same inputs, one process.

    Returns rows ``(component, B, reference us, compiled us)``: the minimum wall time over repeats (the
    load-robust statistic on a shared machine). Inputs are synthetic but shaped like the env's (17 states,
    16 channels, m = 32 rows with the GNSS sparsity of H).
    """
    import copy

    import nav_filters.forms  # noqa: F401
    from nav_filters import measurements as meas
    from nav_filters.adaptive.base import EpochContext
    from nav_filters.adaptive.innovation import innovation_traces, innovation_traces_reference
    from nav_filters.adaptive.sage_husa import SageHusa
    from nav_filters.forms import KalmanFilter
    from nav_filters.forms.base import prepare_measurement, prepare_measurement_reference

    def tmin(fn, reps):
        best = np.inf
        for _ in range(reps):
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
        return 1e6 * best

    out = []
    n, C = 17, 16
    m = 2 * C
    for B in batches:
        reps = repeats or (200 if B == 1 else 5)
        rng = np.random.default_rng(0)

        def spd(k, s=1.0):
            A = rng.normal(size=(B, k, k))
            return s * (A @ A.mT + k * np.eye(k))

        r = np.tile([4.0e6, 0.6e6, 4.9e6], (B, 1)) + rng.normal(0, 100, (B, 3))
        v = rng.normal(0, 10, (B, 3))
        up = r / np.linalg.norm(r, axis=1, keepdims=True)
        d = rng.normal(size=(B, C, 3)) + 2.0 * up[:, None, :]
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        sat, sv = r[:, None, :] + 2.2e7 * d, rng.normal(0, 2500, (B, C, 3))
        gmask = rng.random((B, C)) < 0.8
        pr = np.linalg.norm(sat - r[:, None], axis=-1)
        g_args = (r, v, rng.normal(0, 100, B), rng.normal(0, 1, B), sat, sv, pr, rng.normal(0, 100, (B, C)),
                  np.full((B, C), 9.0), np.full((B, C), 0.01), gmask)
        dz, H, Rv, row_mask, u = meas.gnss_innovations(*g_args)
        out.append(("innovations (ranging, dz, H, R)", B, tmin(lambda: meas.gnss_innovations_reference(*g_args), reps),
                    tmin(lambda: meas.gnss_innovations(*g_args), reps)))
        out.append(("dop", B, tmin(lambda: meas.dop_reference(u, gmask), reps), tmin(lambda: meas.dop(u, gmask), reps)))
        p_args = (dz, H, Rv, row_mask, np.float64)
        out.append(("prepare_measurement (x2 per update)", B,
                    tmin(lambda: prepare_measurement_reference(*p_args), reps),
                    tmin(lambda: prepare_measurement(*p_args), reps)))
        prep = prepare_measurement(*p_args)
        P0 = spd(n)
        kf = KalmanFilter(P0)
        out.append(("kf Joseph update", B, tmin(lambda: kf._update_reference(*prep), reps),
                    tmin(lambda: kf._update(*prep), reps)))
        Q, prior = spd(n, 1e-4), spd(n, 0.01)
        ctx = EpochContext(pending=True, Phi=None, Q=Q, prior=prior)
        out.append(("innovation traces (stkf, ma-stkf)", B,
                    tmin(lambda: innovation_traces_reference(prep[0], prep[1], prior, Q, prep[2], prep[3]), reps),
                    tmin(lambda: innovation_traces(prep[0], prep[1], prior, Q, prep[2], prep[3]), reps)))
        law = SageHusa(spd(n, 0.01))
        law._seen[:] = 100
        active = np.ones(B, bool)
        dd = np.full(B, 0.05)
        law._plan(prep[0], prep[1], prep[2], prep[3], ctx)
        out.append(("sage-husa R law (compiled: whole _plan)", B,
                    tmin(lambda: law._r_scales_reference(prep[0], prep[1], prep[2], prep[3], ctx, dd, active), reps),
                    tmin(lambda: law._plan(prep[0], prep[1], prep[2], prep[3], ctx), reps)))
        law.inner.P = prior + spd(n, 0.1)
        dx = rng.normal(size=(B, n))
        rows = np.ones(B, bool)
        la, lb = copy.deepcopy(law), copy.deepcopy(law)
        out.append(("sage-husa Q law (eigh)", B, tmin(lambda: la._adapt_q_reference(rows, dd, ctx, dx), reps),
                    tmin(lambda: lb._adapt_q(rows, dd, ctx, dx), reps)))
        out.append(("closed-loop feedback", B, *_time_feedback(B, reps, tmin)))
    return out


def _time_feedback(B, reps, tmin):
    """(reference us, compiled us) of the navigator's closed-loop feedback on B copies of one world's start."""
    from envs.episodes import initial_covariance, process_noise_for
    from envs.sim.world import generate_world
    from nav_filters.navigator import Navigator, NavigatorConfig

    w = generate_world("open-sky", [0])
    i = w.init
    rep = lambda a: np.repeat(np.asarray(a), B, 0)  # noqa: E731
    nav = Navigator(NavigatorConfig(method="sage-husa", noise=process_noise_for(w)), rep(i.r_e), rep(i.v_e),
                    rep(i.C_eb), rep(initial_covariance(w, "float64")), rep(i.clock_bias_m), rep(i.clock_drift_mps))
    dx = np.random.default_rng(1).normal(size=(B, 17)) * 1e-3
    return tmin(lambda: nav._feedback_reference(dx), reps), tmin(lambda: nav._feedback(dx), reps)


def _run_cell(root, kind, method, B, steps, episode_s, scenario, transition="exact", stat="mean"):
    """One benchmark cell in a fresh process on the source tree ``root``; returns its JSON result (a rate cell's
    steps/s by ``stat``, as :func:`bench_env`)."""
    env = dict(os.environ, NAVGYM_BENCH_ROOT=root)
    cmd = [sys.executable, os.path.abspath(__file__), "--cell", kind, method, str(B), str(steps), str(episode_s),
           scenario, transition, stat]
    out = subprocess.run(cmd, env=env, cwd=root, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _run_before(root, kind, method, B, steps, episode_s, scenario, transition, stat="mean"):
    """The *before* cell of ``--compare``: ``transition`` in the tree ``root``, or its exact default where that
    tree has no such mode (its env raises). Returns (JSON result, whether it fell back)."""
    try:
        return _run_cell(root, kind, method, B, steps, episode_s, scenario, transition, stat), False
    except subprocess.CalledProcessError:
        if transition == "exact":
            raise
        return _run_cell(root, kind, method, B, steps, episode_s, scenario, "exact", stat), True


def _print_rounds(args, batches, n_steps, root):
    """The throughput table of ``--rounds N`` in one tree: every cell (method, B, mode) runs N times in fresh
    processes, all cells in turn per round (so a slow minute of the machine falls on every cell alike, not on
    one); each row the median steps/s (and of the reset and CPU times) with the lowest and highest of the N."""
    cells = [(m, B, tr) for m in args.methods for B in batches for tr in args.transitions]
    runs = {c: [] for c in cells}
    for r in range(args.rounds):
        for m, B, tr in cells:
            runs[(m, B, tr)].append(_run_cell(root, "rate", m, B, n_steps(B), args.episode_s, args.scenario, tr,
                                              args.stat))
        print(f"round {r + 1}/{args.rounds} done", file=sys.stderr, flush=True)
    for m, B, tr in cells:
        res = np.asarray(runs[(m, B, tr)], float)
        t_reset, rate, cpu = np.median(res, axis=0)
        spread = f"{res[:, 1].min():.0f}-{res[:, 1].max():.0f}"
        _print_rate_row(_label(m, tr), B, t_reset, rate, cpu, f" {spread:>18s}")


def _print_headline(args, n_steps, here, other=None):
    """The end-to-end headline (:func:`bench_end_to_end`) beside the step-only rate of the same cell, for each
    method and B of ``--e2e-batches``, in the env default (fused) mode; every figure from fresh processes, the
    median of ``--rounds`` (with ``other``: alternately in that tree too, and the speed-up)."""
    cpus = usable_cpus()
    print(f"\nend to end, the headline: {args.scenario}, {args.episode_s:g} s episodes, zero actions, automatic "
          f"resets included (each draws its rows' new worlds), the first episode untimed, no prefetch, env default mode "
          f"(fused); "
          f"{'median of ' + str(args.rounds) + ' runs' if args.rounds > 1 else 'one run'} per cell")
    if not other:
        print(f"resets: their share of the e2e wall time and of its CPU time (all threads); cores busy: CPU time / "
              f"wall time; {cpus}-core bound: the e2e steps/s if the same CPU work kept all {cpus} cores busy "
              f"(no scheduling of it does better here)")
    cols = ("e2e steps/s", "step-only", "resets")
    hdr = (f"{'method':{NAME_W}s} {'B':>5s} " + (" ".join(f"{c + ' before':>18s} {'after':>9s}" for c in cols) + " e2e speed-up"
                                           if other else " ".join(f"{c:>12s}" for c in cols)
                                           + f" {'reset CPU':>10s} {'cores busy':>11s} {f'{cpus}-core bound':>13s}"))
    print(hdr + "\n" + "-" * len(hdr))
    for m in args.methods:
        for B in args.e2e_batches:
            runs = {}
            for _ in range(args.rounds):
                for tree in ([other] if other else []) + [here]:
                    e2e = _run_cell(tree, "e2e", m, B, 0, args.episode_s, args.scenario, "fused")
                    rate = _run_cell(tree, "rate", m, B, n_steps(B), args.episode_s, args.scenario, "fused", args.stat)
                    runs.setdefault(tree, []).append((e2e[0], rate[1], e2e[1], e2e[3], e2e[0] * e2e[2] / (1e3 * B),
                                                      cpu_bound(B, e2e[2], cpus)))
            med = {tree: np.median(np.asarray(v, float), axis=0) for tree, v in runs.items()}
            a = med[here]
            if other:
                b = med[other]
                print(f"{m:{NAME_W}s} {B:5d} {b[0]:18.0f} {a[0]:9.0f} {b[1]:18.0f} {a[1]:9.0f} {100 * b[2]:17.0f}% "
                      f"{100 * a[2]:8.0f}% {a[0] / b[0]:11.2f}x", flush=True)
            else:
                print(f"{m:{NAME_W}s} {B:5d} {a[0]:12.0f} {a[1]:12.0f} {100 * a[2]:11.0f}% {100 * a[3]:9.0f}% "
                      f"{a[4]:11.2f} {a[5]:13.0f}", flush=True)
    print()


def _print_rate_row(label, B, t_reset, rate, cpu, extra=""):
    """One row of the single-tree throughput table (``extra``: the rounds' range column)."""
    print(f"{label:{NAME_W}s} {B:5d} {t_reset:10.2f} {rate:12.0f} {1e3 * B / rate:9.2f} {cpu:12.2f}{extra}", flush=True)


def _cell_main(kind, method, B, steps, episode_s, scenario, transition, stat="mean"):
    B, steps, episode_s = int(B), int(steps), float(episode_s)
    if kind == "rate":
        print(json.dumps(bench_env(method, B, steps, episode_s, scenario, transition, stat=stat)))
    elif kind == "e2e":
        print(json.dumps(bench_end_to_end(method, B, episode_s, scenario, transition)))
    else:
        print(json.dumps(profile_env(method, B, steps, episode_s, scenario, transition, cpu=kind == "cpu-profile")))


def print_filterpy(batches, episode_s, scenario, steps_of):
    """filterpy's plain loop against navgym's env step (sage-husa, both transitions), per CPU second."""
    from filterpy_baseline import N_MEAS, SAMPLES_PER_EPOCH, filterpy_rate
    print(f"\nside by side with the plain loop: filterpy KalmanFilter, 17 states, {SAMPLES_PER_EPOCH} predict() + "
          f"1 update() of {N_MEAS} measurements per epoch (no mechanization, no adaptive law), one Python object "
          f"per filter;\nnavgym: GnssIns/SageHusa-v1 env steps ({scenario}; each = {SAMPLES_PER_EPOCH} IMU samples "
          f"of mechanization + the covariance + a Sage-Husa update of ~20 measurements + feedback + observation)")
    fp = filterpy_rate()
    hdr = f"{'loop':28s} {'B':>5s} {'epochs/s wall':>14s} {'per CPU s (core)':>17s} {'vs filterpy/core':>17s}"
    print(hdr + "\n" + "-" * len(hdr))
    if fp is None:
        print("filterpy: skipped (not installed; pip install -e \".[bench]\")")
    else:
        print(f"{'filterpy KalmanFilter':28s} {1:5d} {fp[0]:14.0f} {fp[1]:17.0f} {1.0:16.2f}x", flush=True)
    for B in batches:
        for tr in TRANSITIONS:
            _, rate, cpu_ms = bench_env("sage-husa", B, steps_of(B), episode_s, scenario, tr)
            per_cpu = 1e3 * B / cpu_ms
            ratio = f"{per_cpu / fp[1]:16.2f}x" if fp else f"{'-':>17s}"
            print(f"{'navgym ' + _label('sage-husa', tr):28s} {B:5d} {rate:14.0f} {per_cpu:17.0f} {ratio}", flush=True)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="B up to 256, fewer steps")
    p.add_argument("--methods", nargs="+", default=DEFAULT_METHODS, choices=list(METHOD_ENV))
    p.add_argument("--batches", nargs="+", type=int, default=None,
                   help="batch sizes (1 = the single env via gym.make; default 1 16 256 1024)")
    p.add_argument("--steps", type=int, default=None, help="timed steps per measurement")
    p.add_argument("--stat", choices=("mean", "median"), default="mean",
                   help="steps/s from the total time (mean) or the median step time (robust to load spikes)")
    p.add_argument("--episode-s", type=float, default=60.0, help="episode length [s] (memory: B x IMU samples)")
    p.add_argument("--scenario", default="noise-burst")
    p.add_argument("--no-profile", action="store_true")
    p.add_argument("--e2e-batches", nargs="+", type=int, default=None,
                   help="batch sizes of the end-to-end headline (resets included; default 1 1024, --quick 1 256)")
    p.add_argument("--no-headline", action="store_true", help="skip the end-to-end headline")
    p.add_argument("--headline-only", action="store_true", help="only the end-to-end headline")
    p.add_argument("--profile-only", action="store_true", help="skip the throughput table")
    p.add_argument("--cpu-profile", action="store_true",
                   help="stage profile in process CPU time (all threads) instead of wall time")
    p.add_argument("--components", action="store_true",
                   help="only time each compiled kernel of the step against its numpy reference (B = 1, 1024)")
    p.add_argument("--compare", metavar="DIR", default=None,
                   help="also run every cell in the source tree DIR, alternately in fresh processes")
    p.add_argument("--rounds", type=int, default=1,
                   help="run each throughput cell this many times in fresh processes (with --compare: in each tree, "
                        "alternately) and print the medians with the range (for a machine whose speed swings "
                        "between runs)")
    p.add_argument("--transitions", nargs="+", default=list(TRANSITIONS), choices=TRANSITIONS,
                   help="transition modes to run (exact: the reference; averaged: exact_transition=False; fused: "
                        "also fused_update=True, the env default)")
    p.add_argument("--accuracy", action="store_true",
                   help="only the accuracy table: the fast modes vs the exact transition on every built-in scenario")
    p.add_argument("--accuracy-episodes", type=int, default=24, help="paired episodes per scenario (--accuracy)")
    p.add_argument("--accuracy-max-s", type=float, default=700.0, help="longest simulated episode [s] (--accuracy)")
    p.add_argument("--accuracy-scenarios", nargs="+", default=None, help="scenarios (--accuracy; default: all)")
    p.add_argument("--accuracy-nees-runs", type=int, default=20, help="matched-scenario NEES runs (--accuracy)")
    p.add_argument("--kernel-time", action="store_true",
                   help="only the time of a step inside the compiled kernels against the Python around them (the "
                        "first of --methods, fused; default B = 1, 1024)")
    p.add_argument("--filterpy", action="store_true",
                   help="only the side-by-side figure against filterpy's KalmanFilter loop (default B = 1, 1024)")
    return p


def _run_single_table(args, p) -> bool:
    """The tables that run alone (``--accuracy``, ``--components``, ``--kernel-time``, ``--filterpy``): print the
    one asked for and return True; False when none is."""
    if args.accuracy:
        from transition_accuracy import print_accuracy
        print_accuracy(episodes=args.accuracy_episodes, max_duration_s=args.accuracy_max_s,
                       scenarios=args.accuracy_scenarios, nees_runs=args.accuracy_nees_runs)
    elif args.components:
        print("compiled kernels against their numpy references (min wall time, same inputs, one process)")
        print(f"{'component':42s} {'B':>5s} {'numpy [us]':>12s} {'compiled [us]':>14s} {'speed-up':>9s}")
        for name, B, t_ref, t_new in bench_components(tuple(args.batches or (1, 1024))):
            print(f"{name:42s} {B:5d} {t_ref:12.1f} {t_new:14.1f} {t_ref / t_new:8.1f}x", flush=True)
    elif args.kernel_time:
        from kernel_time import kernel_share, print_kernel_share
        m = args.methods[0]
        for B in args.batches or [1, 1024]:
            env = _make(m, B, args.episode_s, args.scenario, "fused")
            env.reset(seed=0)
            n = args.steps or (20 if B == 1 else 8)
            acts = _actions(env.action_space, WARMUP_STEPS + 2 * n)
            if len(acts) >= args.episode_s:  # 1 Hz GNSS: stay inside one episode
                p.error(f"--steps {n}: {len(acts)} steps do not fit in one {args.episode_s:g} s episode")
            for a in acts[:WARMUP_STEPS]:
                env.step(a)
            step, per_kernel = kernel_share(env, acts[WARMUP_STEPS:WARMUP_STEPS + n])
            print_kernel_share(f"{_label(m, 'fused')} ({args.scenario})", B, step, per_kernel)
            env.close()
    elif args.filterpy:
        steps = args.steps or (20 if args.quick else 30)
        print_filterpy(args.batches or [1, 1024], args.episode_s, args.scenario, lambda B: steps if B == 1 else 8)
    else:
        return False
    return True


def _print_rate_table(args, batches, n_steps, here, other) -> None:
    """The step-only throughput table: each method x B x transition mode, here (and in ``other`` with
    ``--compare``, alternately, ``--rounds`` times, medians)."""
    if other:
        hdr = (f"{'method':{NAME_W}s} {'B':>5s} {'steps/s before':>15s} {'after':>10s} {'speed-up':>9s} "
               f"{'cpu ms before':>14s} {'after':>9s} {'reset s before':>15s} {'after':>7s}"
               + (f" {'rounds: speed-ups':>18s}" if args.rounds > 1 else ""))
    else:
        hdr = (f"{'method':{NAME_W}s} {'B':>5s} {'reset [s]':>10s} {'steps/s':>12s} {'ms/step':>9s} {'cpu ms/step':>12s}"
               + (f" {'rounds: steps/s':>18s}" if args.rounds > 1 else ""))
    print("\n" + hdr + "\n" + "-" * len(hdr))
    rounds_here = args.rounds > 1 and not other  # the table of _print_rounds instead of the loop below
    if rounds_here:
        _print_rounds(args, batches, n_steps, here)
        return
    for m in args.methods:
        for B in batches:
            cell = ("rate", m, B, n_steps(B), args.episode_s, args.scenario)
            for tr in args.transitions:
                lab = _label(m, tr)
                if not other:
                    t_reset, rate, cpu = bench_env(m, B, n_steps(B), args.episode_s, args.scenario, tr,
                                                   stat=args.stat)
                    _print_rate_row(lab, B, t_reset, rate, cpu)
                    continue
                before, after = [], []
                for _ in range(args.rounds):
                    rb, fell_back = _run_before(other, *cell, tr, args.stat)  # in the same mode if it has it
                    before.append(rb)
                    after.append(_run_cell(here, *cell, tr, args.stat))
                lab += "*" if fell_back else ""
                rb, ra = np.median(before, axis=0), np.median(after, axis=0)
                ups = [a[1] / b[1] for a, b in zip(after, before)]
                spread = f" {min(ups):12.2f}-{max(ups):.2f}x" if args.rounds > 1 else ""
                print(f"{lab:{NAME_W}s} {B:5d} {rb[1]:15.0f} {ra[1]:10.0f} {ra[1] / rb[1]:8.2f}x {rb[2]:14.2f} "
                      f"{ra[2]:9.2f} {rb[0]:15.2f} {ra[0]:7.2f}{spread}", flush=True)


def _print_profile(args, batches, n_steps, here, other) -> None:
    """The profile of one step by stage (sage-husa, or the first method) at B = 1 and the largest B, per
    transition mode (and the ``--compare`` tree's first mode)."""
    m = "sage-husa" if "sage-husa" in args.methods else args.methods[0]
    cols = []
    for B in sorted({1, max(batches)}):
        cell = ("cpu-profile" if args.cpu_profile else "profile", m, B, n_steps(B), args.episode_s, args.scenario)
        if other:
            tr0 = args.transitions[0]
            rb, fell_back = _run_before(other, *cell, tr0)
            cols.append((f"B={B} before{'' if fell_back else _SHORT[tr0]}", rb))
        for tr in args.transitions:
            if other:
                cols.append((f"B={B} after{_SHORT[tr]}", _run_cell(here, *cell, tr)))
            else:
                cols.append((f"B={B}{_SHORT[tr]}", profile_env(*cell[1:], tr, cpu=args.cpu_profile)))
    print(f"\nprofile of one step, {m}: {'CPU' if args.cpu_profile else 'wall'} ms per step (share)")
    print(f"{'stage':14s}" + "".join(f"{name:>20s}" for name, _ in cols))
    for s in STAGES:
        print(f"{s:14s}" + "".join(f"{r[0][s]:11.3f} ({100 * r[0][s] / r[1]:4.1f}%)" for _, r in cols))
    print(f"{'total':14s}" + "".join(f"{r[1]:11.3f}         " for _, r in cols))


def main(argv=None):
    p = _parser()
    args = p.parse_args(argv)
    if args.rounds < 1:
        p.error(f"--rounds must be at least 1, got {args.rounds}")
    if _run_single_table(args, p):
        return
    batches = args.batches or ([1, 16, 256] if args.quick else [1, 16, 256, 1024])
    args.e2e_batches = args.e2e_batches or ([1, 256] if args.quick else [1, 1024])
    print(f"navgym env throughput: scenario {args.scenario}, episode {args.episode_s:g} s, "
          f"{os.cpu_count()} CPUs; one step = one GNSS epoch (100 IMU samples + update); steps/s from the "
          f"{'median step time' if args.stat == 'median' else 'total time'}")

    def n_steps(B):
        if args.steps:
            return args.steps
        if args.quick:
            return 20 if B == 1 else 5
        return 40 if B == 1 else (20 if B <= 16 else 8)

    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    other = os.path.abspath(args.compare) if args.compare else None
    if other:
        print(f"before = {other}\nafter  = {here}")
        if args.rounds > 1:
            print(f"each figure the median of {args.rounds} alternating runs per tree")
    elif args.rounds > 1:
        beside = "" if args.headline_only else "; in the throughput table their range beside"
        print(f"each figure the median of {args.rounds} runs in fresh processes, cells in turn{beside}")
    if not args.no_headline and not args.profile_only:
        _print_headline(args, n_steps, here, other)
    if args.headline_only:
        return
    if not args.profile_only:
        _print_rate_table(args, batches, n_steps, here, other)
    if not args.no_profile:
        _print_profile(args, batches, n_steps, here, other)

if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--cell":
        _cell_main(*sys.argv[2:10])
    else:
        main()
