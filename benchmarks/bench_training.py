"""PPO training throughput: the native batched vector env vs SB3's DummyVecEnv of single envs, per n_envs and
transition mode, side by side from one run.

For every ``n_envs`` of ``--n-envs`` (default 16, 64, 256) and every mode of ``--transitions`` (default all:
``exact``: the per-sample composition, the envs' default before issue 11; ``averaged``:
``exact_transition=False``; ``fused``: also ``fused_update=True``, the envs' default) it prints the env-steps per second of ``PPO.learn`` on

* the native vector env behind the SB3 adapter (:func:`envs.sb3.make_sb3_vec_env`, what ``train.py rl`` uses),
  with the worlds of its next resets drawn ahead as ``train.py rl`` draws them (``--prefetch-worlds``, default
  its setting ``prefetch_worlds``: :class:`envs.prefetch.WorldPrefetcher`), and without (``no prefetch``),
* a DummyVecEnv of ``n_envs`` single envs (what RL Zoo builds from ``gym.make``), unless ``--no-dummy``,
* the same native vector env stepped alone with random actions (``env only``): the ceiling the env sets,
  and the share of that time spent in automatic resets (``resets``: world generation and filter construction
  for each finished episode; it grows with 1 / episode length),

and the share of the learning time spent outside the env (PPO's rollout glue, the policy forward passes and
the gradient epochs). PPO runs with the hyperparameters of ``train.py rl`` (``agents.training.DEFAULT_HYPERPARAMS
['ppo']``: n_steps 128, batch 256, 10 epochs, [64, 64] MLP, torch's fused Adam; torch on one thread as ``train.py`` sets it,
:func:`agents.training.set_torch_threads`),
without VecNormalize. Each cell first learns one rollout (JIT compilation, first resets), then times
``--rollouts`` rollouts (``n_steps x n_envs`` env steps each) continuing that run as a long training run goes
on (``reset_num_timesteps=False``: no extra reset of every row at the start of the timed part; until
this was noticed that reset, a whole world batch drawn at once, was timed too).

``--compare DIR`` measures instead the native vector env's PPO rate (and the env alone) in this tree and in the
source tree ``DIR`` (e.g. a checkout of an earlier commit), each cell in a fresh process, alternately, and prints
before, after and the speed-up side by side: before/after figures under the same machine load. A mode the
earlier tree's env does not take falls back to that tree's default configuration (marked ``*``; before
issue 11 the exact composition).

``--rounds N`` (with ``--compare``) runs each cell N times in each tree, alternately, and prints the medians
and the range of the per-round PPO speed-ups: here consecutive runs of one cell differed by up to 20%.

Usage: ``python benchmarks/bench_training.py [--n-envs 16 64 256] [--transitions exact fused] [--no-dummy]
[--compare DIR [--rounds N]]``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.environ.get("NAVGYM_BENCH_ROOT") or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from stage_timing import timed  # noqa: E402  (this script's folder)

import envs  # noqa: E402,F401
from agents.training import DEFAULT_HYPERPARAMS  # noqa: E402

try:
    from agents.training import DEFAULT_SETTINGS  # noqa: E402
    PREFETCH_DEFAULT = int(DEFAULT_SETTINGS.get("prefetch_worlds", 0))
except ImportError:  # pragma: no cover - a source tree before it (--compare)
    PREFETCH_DEFAULT = 0
from envs.sb3 import make_sb3_vec_env  # noqa: E402

try:
    from agents.training import set_torch_threads  # noqa: E402  (torch's thread count as train.py rl sets it)
except ImportError:  # a source tree before it (--compare): the same two steps
    def set_torch_threads(n: int) -> None:
        """Numba's threading layer started first (its one-time ``omp_set_num_threads``), then torch's threads."""
        import numba
        import torch
        numba.get_num_threads()
        torch.set_num_threads(n)

MODES = {"exact": dict(exact_transition=True, fused_update=False),
         "averaged": dict(exact_transition=False, fused_update=False),
         "fused": dict(exact_transition=False, fused_update=True)}
"""Env kwargs of each transition mode (see ``benchmarks/bench_envs.py``)."""


def learn_rate(venv, n_envs: int, rollouts: int) -> float:
    """Env-steps/s of ``PPO.learn`` over ``rollouts`` rollouts after one warm-up rollout."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger
    set_torch_threads(1)  # as train.py rl sets it: after numba's threading layer starts, so that it holds
    hp = dict(DEFAULT_HYPERPARAMS["ppo"])
    policy = hp.pop("policy")
    model = PPO(policy, venv, seed=0, device="cpu", verbose=0, **hp)
    model.set_logger(Logger(None, []))  # SB3's default logger leaves an empty SB3-<time> folder in the temp dir
    steps = hp["n_steps"] * n_envs
    model.learn(total_timesteps=steps)
    t = time.perf_counter()
    model.learn(total_timesteps=rollouts * steps, reset_num_timesteps=False)
    return rollouts * steps / (time.perf_counter() - t)


def env_rate(venv, n_envs: int, steps: int) -> tuple[float, float]:
    """(env-steps/s, share of the time in automatic resets) of the SB3 vector env stepped with random actions
    (``steps`` batched steps, at least two whole episodes so that the resets come at their rate in training)."""
    rng = np.random.default_rng(0)
    venv.reset()
    shape = (n_envs,) + venv.action_space.shape
    acts = [rng.uniform(-1, 1, shape).astype(np.float32) for _ in range(8)]
    venv.step(acts[0])
    core = venv.venv.core
    steps = max(steps, 2 * core.M)
    spent = [0.0]
    core.reset_rows = timed(core.reset_rows, spent, 0)
    try:
        t = time.perf_counter()
        for i in range(steps):
            venv.step(acts[i % 8])
        wall = time.perf_counter() - t
    finally:
        del core.reset_rows  # back to the method
    return steps * n_envs / wall, spent[0] / wall


def _native_env(env_id, n, mode, episode_length, prefetch):
    """(the SB3 native vector env, whether it draws worlds ahead): ``prefetch_worlds=prefetch`` where the tree's
    env takes it (a tree before :mod:`envs.prefetch` does not: then without)."""
    kw = dict(seed=0, episode_length_s=episode_length, **MODES.get(mode, {}))
    if prefetch:
        try:
            venv = make_sb3_vec_env(env_id, n, prefetch_worlds=prefetch, **kw)
        except (TypeError, ValueError) as exc:
            if "prefetch_worlds" not in str(exc):
                raise
        else:
            venv.venv._prefetch.wait_ready()  # its start-up (navgym's import) is not PPO's rate
            return venv, True
    return make_sb3_vec_env(env_id, n, **kw), False


def native_cell(env_id, n, mode, rollouts, episode_length, prefetch=0):
    """(PPO env-steps/s, env-only env-steps/s, reset share, drew ahead) of the native vector env in this
    process (``prefetch``: its ``prefetch_worlds``, where the tree has it)."""
    n_steps = DEFAULT_HYPERPARAMS["ppo"]["n_steps"]
    native, ahead = _native_env(env_id, n, mode, episode_length, prefetch)
    r_native = learn_rate(native, n, rollouts)
    r_env, reset_share = env_rate(native, n, max(8, rollouts * n_steps // 4))
    native.close()
    return r_native, r_env, reset_share, ahead


def _run_cell(root, env_id, n, mode, rollouts, episode_length, prefetch=0):
    """:func:`native_cell` in a fresh process on the source tree ``root`` (its JSON result)."""
    cmd = [sys.executable, os.path.abspath(__file__), "--cell", env_id, str(n), mode, str(rollouts),
           str(episode_length), str(prefetch)]
    out = subprocess.run(cmd, env=dict(os.environ, NAVGYM_BENCH_ROOT=root), cwd=root, capture_output=True,
                         text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _before_cell(other, a, n, mode):
    """(the before tree's cell result, mark): ``mode`` there, or its own default where it has no such mode."""
    try:
        return _run_cell(other, a.env, n, mode, a.rollouts, a.episode_length, a.prefetch_worlds), ""
    except subprocess.CalledProcessError:  # a tree before the transition modes: its own default
        return _run_cell(other, a.env, n, "default", a.rollouts, a.episode_length, a.prefetch_worlds), "*"


def compare(a, other):
    """The ``--compare`` table: every cell before (tree ``other``) and after (this tree), alternately, ``a.rounds``
    times each (then the medians, and the range of the per-round PPO speed-ups)."""
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    print(f"before = {other}\nafter  = {here}\n")
    print(f"worlds drawn ahead: prefetch_worlds={a.prefetch_worlds} where a tree's env takes it (+: only after)")
    if a.rounds > 1:
        print(f"each figure the median of {a.rounds} alternating runs per tree")
    head = (f"\n{'n_envs':>6}  {'transition':<11} {'PPO before':>10} {'after':>8} {'speed-up':>9} "
            f"{'env before':>11} {'after':>8} {'resets before':>14} {'after':>6}"
            + (f" {'rounds: speed-ups':>18}" if a.rounds > 1 else ""))
    print(head + "\n" + "-" * (len(head) - 1))
    for n in a.n_envs:
        for mode in a.transitions:
            before, after = [], []
            for _ in range(a.rounds):
                rb, mark = _before_cell(other, a, n, mode)
                before.append(rb)
                after.append(_run_cell(here, a.env, n, mode, a.rollouts, a.episode_length, a.prefetch_worlds))
            mark += "" if before[0][3] == after[0][3] else "+"
            ups = [ra[0] / rb[0] for ra, rb in zip(after, before)]
            rb, ra = np.median(np.array(before, float), axis=0), np.median(np.array(after, float), axis=0)
            spread = f" {min(ups):12.2f}-{max(ups):.2f}x" if a.rounds > 1 else ""
            print(f"{n:>6}  {mode + mark:<11} {rb[0]:10.0f} {ra[0]:8.0f} {ra[0] / rb[0]:8.2f}x {rb[1]:11.0f} "
                  f"{ra[1]:8.0f} {rb[2]:14.0%} {ra[2]:6.0%}{spread}", flush=True)


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "--cell":  # one cell of --compare, in a fresh process
        env_id, n, mode, rollouts, episode_length, prefetch = sys.argv[2:8]
        print(json.dumps(native_cell(env_id, int(n), mode, int(rollouts), float(episode_length), int(prefetch))))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="GnssIns/SageHusa-v1")
    ap.add_argument("--n-envs", type=int, nargs="+", default=[16, 64, 256])
    ap.add_argument("--transitions", nargs="+", choices=list(MODES), default=list(MODES))
    ap.add_argument("--rollouts", type=int, default=2, help="timed rollouts per cell (n_steps x n_envs steps each)")
    ap.add_argument("--episode-length", type=float, default=60.0, help="episode length [s]")
    ap.add_argument("--no-dummy", action="store_true", help="skip the DummyVecEnv of single envs")
    ap.add_argument("--prefetch-worlds", type=int, default=PREFETCH_DEFAULT,
                    help="the native env's prefetch_worlds (default: train.py rl's setting; 0: off, and no "
                         "'no prefetch' column)")
    ap.add_argument("--compare", metavar="DIR", default=None,
                    help="native vector env before (source tree DIR) / after (this tree), side by side")
    ap.add_argument("--rounds", type=int, default=1,
                    help="--compare: run each cell this many times in each tree, alternately, and print the medians "
                         "with the range of the per-round speed-ups (for a machine whose speed swings)")
    a = ap.parse_args()
    if min(a.n_envs) < 1 or a.rollouts < 1 or a.rounds < 1 or not a.episode_length > 0 or a.prefetch_worlds < 0:
        ap.error("--n-envs, --rollouts and --rounds must be >= 1, --episode-length > 0 and --prefetch-worlds >= 0")
    if a.compare is not None and not os.path.isdir(os.path.join(a.compare, "envs")):
        ap.error(f"--compare: {a.compare} is not a navgym source tree (no envs/ in it)")
    from stable_baselines3.common.env_util import make_vec_env
    n_steps = DEFAULT_HYPERPARAMS["ppo"]["n_steps"]
    print(f"PPO on {a.env} (train.py rl hyperparameters: n_steps {n_steps}, batch "
          f"{DEFAULT_HYPERPARAMS['ppo']['batch_size']}, {DEFAULT_HYPERPARAMS['ppo']['n_epochs']} epochs), episodes "
          f"{a.episode_length:.0f} s, {a.rollouts} timed rollouts per cell, {os.cpu_count()} CPUs; env-steps/s\n")
    if a.compare is not None:
        return compare(a, os.path.abspath(a.compare))
    pf = a.prefetch_worlds
    if pf:
        print(f"native: prefetch_worlds={pf} (train.py rl's setting); no prefetch: the same env drawing every world "
              f"at its reset; env only, resets, not env: without prefetch\n")
    head = f"{'n_envs':>6}  {'transition':<10} {'native':>9} {'no prefetch':>12} {'dummy':>9} {'native/dummy':>13} " \
           f"{'env only':>9} {'resets':>7} {'not env':>8}"
    print(head)
    print("-" * len(head))
    best = {}
    for n in a.n_envs:
        for mode in a.transitions:
            kw = dict(episode_length_s=a.episode_length, **MODES[mode])
            r_plain, r_env, reset_share, _ = native_cell(a.env, n, mode, a.rollouts, a.episode_length)
            r_native = native_cell(a.env, n, mode, a.rollouts, a.episode_length, pf)[0] if pf else r_plain
            r_dummy = float("nan")
            if not a.no_dummy:
                dummy = make_vec_env(lambda kw=kw: gym.make(a.env, **kw), n_envs=n, seed=0)
                r_dummy = learn_rate(dummy, n, a.rollouts)
                dummy.close()
            not_env = 1.0 - r_plain / r_env  # share of PPO.learn's time outside env.step
            plain = f"{r_plain:12.0f}" if pf else f"{'':>12}"
            print(f"{n:>6}  {mode:<10} {r_native:9.0f} {plain} {r_dummy:9.0f} {r_native / r_dummy:13.2f} "
                  f"{r_env:9.0f} {reset_share:7.0%} {not_env:8.0%}", flush=True)
            if r_native > best.get(mode, (0, 0))[1]:
                best[mode] = (n, r_native)
    print()
    for mode, (n, r) in best.items():
        print(f"fastest n_envs with the {mode} transition: {n} ({r:.0f} env-steps/s)")
    if "exact" in best:
        for mode, (n, r) in best.items():
            if mode != "exact":
                print(f"{mode} at its fastest n_envs vs exact at its fastest: {r / best['exact'][1]:.2f}x")


if __name__ == "__main__":
    main()
