"""Where the time of ``train.py rl --algo recurrentppo --quick`` goes: rollout vs gradient steps, per setting.

    python benchmarks/bench_recurrent.py [--timesteps 2048]

Prints, for the quick preset's hyperparameters and variants (torch threads, n_steps, batch size), the
env-steps/s of ``learn`` and the share spent in RecurrentPPO's ``train`` (the LSTM's per-step loop over
sequences with episode starts, forward and backward). Not a test: figures for the README and help text.
"""
from __future__ import annotations

import argparse
import time


def run(timesteps: int, threads: int, n_envs: int, hyper: dict) -> tuple[float, float]:
    import torch
    from sb3_contrib import RecurrentPPO
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    import envs  # noqa: F401
    from agents.training import DEFAULT_HYPERPARAMS, QUICK
    from envs.sb3 import make_sb3_vec_env

    torch.set_num_threads(threads)
    h = {**DEFAULT_HYPERPARAMS["recurrentppo"], **QUICK["hyper"]["recurrentppo"], **hyper}
    policy = h.pop("policy")
    venv = VecNormalize(VecMonitor(make_sb3_vec_env("GnssIns/SageHusa-v1", n_envs, seed=0, **QUICK["env_kwargs"])),
                        gamma=h["gamma"])
    model = RecurrentPPO(policy, venv, seed=0, device="cpu", verbose=0, **h)
    model.set_logger(Logger(None, []))  # SB3's default logger leaves an empty SB3-<time> folder in the temp dir
    spent = [0.0]
    inner = model.train

    def timed_train():
        t = time.perf_counter()
        inner()
        spent[0] += time.perf_counter() - t
    model.train = timed_train
    t0 = time.perf_counter()
    model.learn(total_timesteps=timesteps)
    wall = time.perf_counter() - t0
    return timesteps / wall, spent[0] / wall


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--timesteps", type=int, default=2048, help="env steps per setting (default: 2048)")
    a = ap.parse_args()
    settings = [("quick preset (n_steps 64, batch 256, 5 epochs), 2 threads", 2, 8, {}),
                ("quick preset, 1 torch thread", 1, 8, {}),
                ("1 thread, n_steps 128, batch 512", 1, 8, dict(n_steps=128, batch_size=512)),
                ("1 thread, 16 envs, n_steps 64, batch 512", 1, 16, dict(batch_size=512))]
    print(f"{'setting':<58s} {'env-steps/s':>12s} {'train share':>12s}")
    for name, threads, n_envs, hyper in settings:
        sps, share = run(a.timesteps, threads, n_envs, hyper)
        print(f"{name:<58s} {sps:12.1f} {100 * share:11.0f}%", flush=True)


if __name__ == "__main__":
    main()
