"""PPO training throughput: the native batched vector env vs SB3's DummyVecEnv of single envs, per n_envs and
transition mode, side by side from one run.

For every ``n_envs`` of ``--n-envs`` (default 16, 64, 256) and every mode of ``--transitions`` (default all:
``exact``: the per-sample composition, the envs' default before issue 11; ``averaged``:
``exact_transition=False``; ``fused``: also ``fused_update=True``, the envs' default) it prints the env-steps per second of ``PPO.learn`` on

* the native vector env behind the SB3 adapter (:func:`envs.sb3.make_sb3_vec_env`, what ``train.py rl`` uses),
* a DummyVecEnv of ``n_envs`` single envs (what RL Zoo builds from ``gym.make``), unless ``--no-dummy``,
* the same native vector env stepped alone with random actions (``env only``): the ceiling the env sets,
  and the share of that time spent in automatic resets (``resets``: world generation and filter construction
  for each finished episode; it grows with 1 / episode length),

and the share of the learning time spent outside the env (PPO's rollout glue, the policy forward passes and
the gradient epochs). PPO runs with the hyperparameters of ``train.py rl`` (``agents.training.DEFAULT_HYPERPARAMS
['ppo']``: n_steps 128, batch 256, 10 epochs, [64, 64] MLP; torch on one thread as ``train.py`` sets it),
without VecNormalize. Each cell first learns one rollout (JIT compilation, first resets), then times
``--rollouts`` rollouts (``n_steps x n_envs`` env steps each).

Usage: ``python benchmarks/bench_training.py [--n-envs 16 64 256] [--transitions exact fused] [--no-dummy]``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import envs  # noqa: E402,F401
from agents.training import DEFAULT_HYPERPARAMS  # noqa: E402
from envs.sb3 import make_sb3_vec_env  # noqa: E402

MODES = {"exact": dict(exact_transition=True, fused_update=False),
         "averaged": dict(exact_transition=False, fused_update=False),
         "fused": dict(exact_transition=False, fused_update=True)}
"""Env kwargs of each transition mode (see ``benchmarks/bench_envs.py``)."""


def learn_rate(venv, n_envs: int, rollouts: int) -> float:
    """Env-steps/s of ``PPO.learn`` over ``rollouts`` rollouts after one warm-up rollout."""
    import torch
    from stable_baselines3 import PPO
    torch.set_num_threads(1)
    hp = dict(DEFAULT_HYPERPARAMS["ppo"])
    policy = hp.pop("policy")
    model = PPO(policy, venv, seed=0, device="cpu", verbose=0, **hp)
    steps = hp["n_steps"] * n_envs
    model.learn(total_timesteps=steps)
    t = time.perf_counter()
    model.learn(total_timesteps=rollouts * steps, reset_num_timesteps=True)
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
    reset_rows, spent = core.reset_rows, [0.0]

    def timed_reset_rows(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return reset_rows(*args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - t0

    core.reset_rows = timed_reset_rows
    try:
        t = time.perf_counter()
        for i in range(steps):
            venv.step(acts[i % 8])
        wall = time.perf_counter() - t
    finally:
        del core.reset_rows  # back to the method
    return steps * n_envs / wall, spent[0] / wall


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="GnssIns/SageHusa-v0")
    ap.add_argument("--n-envs", type=int, nargs="+", default=[16, 64, 256])
    ap.add_argument("--transitions", nargs="+", choices=list(MODES), default=list(MODES))
    ap.add_argument("--rollouts", type=int, default=2, help="timed rollouts per cell (n_steps x n_envs steps each)")
    ap.add_argument("--episode-length", type=float, default=60.0, help="episode length [s]")
    ap.add_argument("--no-dummy", action="store_true", help="skip the DummyVecEnv of single envs")
    a = ap.parse_args()
    if min(a.n_envs) < 1 or a.rollouts < 1 or not a.episode_length > 0:
        ap.error("--n-envs and --rollouts must be >= 1 and --episode-length > 0")
    from stable_baselines3.common.env_util import make_vec_env
    n_steps = DEFAULT_HYPERPARAMS["ppo"]["n_steps"]
    print(f"PPO on {a.env} (train.py rl hyperparameters: n_steps {n_steps}, batch "
          f"{DEFAULT_HYPERPARAMS['ppo']['batch_size']}, {DEFAULT_HYPERPARAMS['ppo']['n_epochs']} epochs), episodes "
          f"{a.episode_length:.0f} s, {a.rollouts} timed rollouts per cell, {os.cpu_count()} CPUs; env-steps/s\n")
    head = f"{'n_envs':>6}  {'transition':<10} {'native':>9} {'dummy':>9} {'native/dummy':>13} {'env only':>9} " \
           f"{'resets':>7} {'not env':>8}"
    print(head)
    print("-" * len(head))
    best = {}
    for n in a.n_envs:
        for mode in a.transitions:
            kw = dict(episode_length_s=a.episode_length, **MODES[mode])
            native = make_sb3_vec_env(a.env, n, seed=0, **kw)
            r_native = learn_rate(native, n, a.rollouts)
            r_env, reset_share = env_rate(native, n, max(8, a.rollouts * n_steps // 4))
            native.close()
            r_dummy = float("nan")
            if not a.no_dummy:
                dummy = make_vec_env(lambda kw=kw: gym.make(a.env, **kw), n_envs=n, seed=0)
                r_dummy = learn_rate(dummy, n, a.rollouts)
                dummy.close()
            not_env = 1.0 - r_native / r_env  # share of PPO.learn's time outside env.step
            print(f"{n:>6}  {mode:<10} {r_native:9.0f} {r_dummy:9.0f} {r_native / r_dummy:13.2f} {r_env:9.0f} "
                  f"{reset_share:7.0%} {not_env:8.0%}", flush=True)
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
