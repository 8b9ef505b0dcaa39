"""PPO training throughput: the native batched vector env vs SB3's DummyVecEnv of single envs (same n_envs).

Prints env-steps per second of ``PPO.learn`` on both, side by side, from one run.
Usage: ``python benchmarks/bench_training.py [--n-envs 8] [--timesteps 4096] [--fast]`` (``--fast``: the averaged
transition, ``exact_transition=False``).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import gymnasium as gym  # noqa: E402

import envs  # noqa: E402,F401
from envs.sb3 import make_sb3_vec_env  # noqa: E402


def learn_rate(venv, timesteps: int, n_envs: int) -> float:
    from stable_baselines3 import PPO
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64 * n_envs, n_epochs=5, seed=0, device="cpu", verbose=0)
    model.learn(total_timesteps=64 * n_envs)  # warm-up (JIT compile, first resets)
    t = time.perf_counter()
    model.learn(total_timesteps=timesteps, reset_num_timesteps=True)
    return timesteps / (time.perf_counter() - t)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="GnssIns/SageHusa-v0")
    ap.add_argument("--n-envs", type=int, default=8)
    ap.add_argument("--timesteps", type=int, default=4096)
    ap.add_argument("--episode-length", type=float, default=60.0)
    ap.add_argument("--fast", action="store_true",
                    help="the averaged transition (exact_transition=False) instead of the exact per-sample one")
    a = ap.parse_args()
    from stable_baselines3.common.env_util import make_vec_env
    kw = dict(episode_length_s=a.episode_length, exact_transition=not a.fast)
    native = make_sb3_vec_env(a.env, a.n_envs, seed=0, **kw)
    dummy = make_vec_env(lambda: gym.make(a.env, **kw), n_envs=a.n_envs, seed=0)
    r_native = learn_rate(native, a.timesteps, a.n_envs)
    r_dummy = learn_rate(dummy, a.timesteps, a.n_envs)
    print(f"PPO on {a.env}, n_envs={a.n_envs}, {a.timesteps} steps (episodes {a.episode_length:.0f} s, "
          f"{'averaged' if a.fast else 'exact'} transition)")
    print(f"  native vector env (SB3 adapter): {r_native:8.0f} env-steps/s")
    print(f"  DummyVecEnv of single envs     : {r_dummy:8.0f} env-steps/s")
    print(f"  ratio native / dummy           : {r_native / r_dummy:8.2f}")


if __name__ == "__main__":
    main()
