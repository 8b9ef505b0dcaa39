"""Step time of the robust measurement screens against kf, as a ratio measured in one run.

One step = one GNSS epoch of the navigator as the environments run it (averaged transition, fused update: the
env ids' default): the IMU samples of the epoch (compiled propagation) + the tightly coupled update with the
method's screen + feedback. All methods run on the same ``urban`` world (NLOS and multipath: the screens have
outliers to find), epoch by epoch in turn, so that a load change of a shared machine hits them alike. Printed
per batch size: the median step time of each method [ms per batched step], row-steps/s and the ratio to kf's
(the issue's target: a robust method's step within 1.5x of kf's at B = 1024), and the ratio of the update
alone (``update_gnss``: the screen + the form's update).

Usage: ``python benchmarks/bench_robust.py [--batches 1 1024] [--steps 30] [--episode-s 60]
[--methods kf-fde kf-igg3 kf-huber vb-akf sage-husa+fde] [--scenario urban]``
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

from envs.episodes import navigator_for, satellite_keys  # noqa: E402
from envs.worlds import make_world  # noqa: E402

METHODS = ("kf-fde", "kf-igg3", "kf-huber", "vb-akf", "sage-husa", "sage-husa+fde")
"""The methods timed against kf by default (sage-husa: the registered adaptive law, for scale)."""


def bench(B: int, steps: int, episode_s: float, methods, scenario: str, seed: int = 0) -> dict:
    """``{method: (median step s, median update s)}`` over ``steps`` epochs after 3 untimed ones."""
    world = make_world(scenario, list(range(seed, seed + B)), duration_s=episode_s)
    navs = {m: navigator_for(world, m, exact_transition=False, fused_update=True) for m in ("kf", *methods)}
    g, f, w, ep = world.gnss, world.imu.f_b, world.imu.w_b, world.epoch_idx
    keys = satellite_keys(g)
    dt = 1.0 / world.scenario.imu_rate_hz
    n = min(len(ep) - 1, steps + 3)
    times = {m: ([], []) for m in navs}
    for j in range(1, n + 1):
        sl = slice(ep[j - 1] + 1, ep[j] + 1)
        prr = None if g.prr is None else g.prr[:, j]
        prs = None if g.prr_sigma is None else g.prr_sigma[:, j]
        for m, nav in navs.items():
            t0 = time.perf_counter()
            nav.propagate_epoch(f[:, sl], w[:, sl], dt)
            t1 = time.perf_counter()
            nav.update_gnss(g.sat_pos[:, j], g.sat_vel[:, j], g.pr[:, j], prr, g.pr_sigma[:, j], prs, g.mask[:, j],
                            sat_keys=keys[:, j])
            t2 = time.perf_counter()
            if j > 3:
                times[m][0].append(t2 - t0)
                times[m][1].append(t2 - t1)
    return {m: (float(np.median(a)), float(np.median(b))) for m, (a, b) in times.items()}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--batches", nargs="+", type=int, default=[1, 1024])
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--episode-s", type=float, default=60.0)
    p.add_argument("--methods", nargs="+", default=list(METHODS))
    p.add_argument("--scenario", default="urban")
    a = p.parse_args(argv)
    print(f"navigator step (averaged transition, fused update) on {a.scenario}, median of {a.steps} epochs, "
          f"methods in turn epoch by epoch")
    print("| B | method | ms/step | row-steps/s | step / kf | update ms | update / kf |")
    print("|---|---|---|---|---|---|---|")
    for B in a.batches:
        res = bench(B, a.steps, a.episode_s, a.methods, a.scenario)
        k_step, k_upd = res["kf"]
        for m, (s, u) in res.items():
            print(f"| {B} | {m} | {1e3 * s:.2f} | {B / s:,.0f} | {s / k_step:.2f} | {1e3 * u:.2f} | {u / k_upd:.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
