"""Zero-velocity detectors: inference throughput, in-the-loop overhead and training wall time.

Prints, side by side in one run:

* inference samples/s of every detector (``shoe``, ``are``, ``mag``, ``mv``, ``mlp``, ``lstm``), batched on
  the CPU, in two modes: one-shot over whole streams (B = 64 streams of 60 s at 100 Hz) and streaming
  per GNSS epoch (chunks of 100 samples, as the environments call it); also the streaming step of the
  numpy specification (``compiled=False``: the classical detectors' whole step, the learned detectors'
  features; their network is torch's either way) and the compiled step's speed-up;
* in-the-loop overhead: environment-core steps per second (B = 1 and 16, ``sage-husa``) with ``zupt`` =
  ``none`` / ``truth`` / ``shoe`` / ``lstm``, and ``shoe`` / ``lstm`` with the numpy detector step and
  constraint block (``ZuptSource.compiled = False``), each with its ratio to ``none``;
* training wall time of the default config of ``train.py zupt`` for ``mlp`` and ``lstm`` (skip with
  ``--no-train``; a few minutes each on 2 cores).

The learned detectors use the shipped weights when present, else an untrained network of the default
architecture (the same cost).

Usage: ``python benchmarks/bench_zupt.py [--no-train] [--threads N] [--rounds N]``
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

from nav_filters.zupt import DETECTORS, default_weights_path, make_detector  # noqa: E402


def _detector(name, rate):
    if name in ("mlp", "lstm") and not default_weights_path(name).is_file():
        from nav_filters.zupt.learned import LearnedConfig, LearnedDetector
        return LearnedDetector(LearnedConfig(kind=name), None, rate)
    return make_detector(name, rate)


def bench_inference(B=64, seconds=60.0, rate=100.0, chunk=100):
    from agents.zupt_training import simulate_drives
    s = simulate_drives(list(range(B)), "industrial", rate, seconds)
    n = s.f_b.size // 3
    print(f"\ninference, B = {B} streams x {seconds:g} s at {rate:g} Hz ({n} samples), CPU")
    print(f"{'detector':>8} | {'one-shot samples/s':>18} | {'streaming (100-sample chunks) samples/s':>40} | "
          f"{'streaming, numpy step':>21} | {'speed-up':>8}")

    def streaming(det):
        det.reset()
        t0 = time.perf_counter()
        for a in range(0, s.f_b.shape[1], chunk):
            det.process(s.f_b[:, a:a + chunk], s.w_b[:, a:a + chunk])
        return n / (time.perf_counter() - t0)

    for name in DETECTORS:
        det = _detector(name, rate)
        det.detect(s.f_b[:, :200], s.w_b[:, :200])                   # warm-up (torch import, first calls)
        t0 = time.perf_counter()
        det.detect(s.f_b, s.w_b)
        one_shot = n / (time.perf_counter() - t0)
        fast = streaming(det)
        if hasattr(det, "compiled"):
            det.compiled = False
            slow = streaming(det)
            tail = f" | {slow:21.3g} | {fast / slow:7.1f}x"
        else:
            tail = f" | {'-':>21} | {'-':>8}"
        print(f"{name:>8} | {one_shot:18.3g} | {fast:40.3g}{tail}")


def bench_in_loop(B=16, epochs=60, rounds=3):
    """Row-epochs/s of the environment core per ``zupt`` choice; the cells of a round run alternately and the
    best of ``rounds`` is printed (a shared machine's speed swings between seconds)."""
    import envs.gnss_ins_env as gie
    from envs.config import EnvConfig
    from envs.core import TuningCore
    print(f"\nin the loop: environment core, B = {B}, sage-husa, urban, {epochs} epochs (100 IMU samples each), "
          f"best of {rounds} alternating rounds")
    cells = [(z, True) for z in ("none", "truth", "shoe", "lstm")] + [("shoe", False), ("lstm", False)]
    best = {}
    for _ in range(rounds):
        for z, compiled in cells:
            if z == "lstm" and not default_weights_path("lstm").is_file():
                continue
            core = TuningCore(EnvConfig(scenario="urban", method="sage-husa", episode_length_s=epochs + 5.0, zupt=z),
                              gie.SAGE_HUSA_PARAMS, B)
            core._zupt.compiled = compiled
            core.reset_rows(np.arange(B), list(range(B)))
            act = np.broadcast_to(core.default_action, (B, core.k))
            core.step(act)
            t0 = time.perf_counter()
            for _ in range(epochs):
                core.step(act)
            rate = B * epochs / (time.perf_counter() - t0)
            best[z, compiled] = max(best.get((z, compiled), 0.0), rate)
    base = best["none", True]
    for (z, compiled), rate in best.items():
        label = z if compiled else f"{z} (numpy step and block)"
        print(f"{label:>28} | {rate:10.1f} row-epochs/s | x{rate / base:.2f} of none")
    if ("lstm", True) not in best:
        print(f"{'lstm':>28} | (no shipped weights)")


def bench_training():
    from agents.zupt_training import train_zupt_detector
    print("\ntraining wall time, default config (train.py zupt), this machine:")
    for model in ("mlp", "lstm"):
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            m = train_zupt_detector(model, 0, Path(d), progress=False)
            wall = time.perf_counter() - t0
        tr = m["training"]
        best = m["test"]["heldout_seeds"][model]
        print(f"{model:>5}: {wall:7.1f} s total, {tr['train_seconds']:7.1f} s training, "
              f"{len(tr['epochs'])} epochs; held-out F1 {best['f1']:.4f}, "
              f"false-ZUPT {100 * best['false_zupt_rate']:.3f} %")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-train", action="store_true", help="skip the training wall-time measurement")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    ap.add_argument("--rounds", type=int, default=3,
                    help="in-the-loop cells: alternating rounds, the best printed (default 3; more on a busy machine)")
    a = ap.parse_args()
    import torch
    torch.set_num_threads(a.threads)
    print(f"torch threads: {torch.get_num_threads()}, CPU cores: {os.cpu_count()}")
    bench_inference()
    for B in (1, 16):
        bench_in_loop(B, rounds=a.rounds)
    if not a.no_train:
        bench_training()


if __name__ == "__main__":
    main()
