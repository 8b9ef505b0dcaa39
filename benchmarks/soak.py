"""Soak of every environment id: randomized row-steps checked for the reliability contract (issue 13).

Runs :func:`envs.soak.soak` over every env id x float64/float32 x scenarios x action patterns (bang-bang,
uniform) x IMU grades and prints, per configuration and summed per dtype: row-steps, exceptions that escaped,
row-steps with NaN/inf in obs/reward/info, live rows with a covariance that is not positive definite, and
diverged (flagged) row-steps with their reasons. The contract holds when the exceptions, NaN and non-PD
columns are all 0 (the flagged rows are the isolation at work). Exit status 1 otherwise.

Usage::

    python benchmarks/soak.py [--quick] [--num-envs 8] [--steps 250] [--seeds 0 1]
                              [--scenarios urban outage ...] [--imu consumer industrial]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import envs  # noqa: E402
from envs.soak import ACTION_PATTERNS, SoakCounts, soak  # noqa: E402

SCENARIOS = ("open-sky", "urban", "outage", "noise-burst", "regime-switch", "urban-transition")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 scenarios, one seed, consumer IMU, 130 steps")
    ap.add_argument("--num-envs", type=int, default=8)
    ap.add_argument("--steps", type=int, default=250, help="vector steps per configuration (episodes reset)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--imu", nargs="+", default=["consumer", "industrial"], help="IMU grades")
    a = ap.parse_args(argv)
    if a.quick:
        a.scenarios, a.seeds, a.imu, a.steps = ["urban", "outage", "noise-burst"], [7], ["consumer"], 130
    totals = {"float64": SoakCounts(), "float32": SoakCounts()}
    print(f"{'env id':20s} {'dtype':7s} {'scenario':17s} {'actions':9s} {'imu':10s} {'row-steps':>9s} "
          f"{'exc':>3s} {'NaN':>3s} {'nonPD':>5s} {'flagged':>7s}  time")
    t_all = time.perf_counter()
    for env_id in sorted(envs.ENV_IDS):
        for dtype in ("float64", "float32"):
            for scenario in a.scenarios:
                for actions in ACTION_PATTERNS:
                    for imu in a.imu:
                        c = SoakCounts()
                        t0 = time.perf_counter()
                        for seed in a.seeds:
                            c += soak(env_id, scenario=scenario, dtype=dtype, actions=actions, num_envs=a.num_envs,
                                      steps=a.steps, seed=seed, imu_grade=imu)
                        print(f"{env_id:20s} {dtype:7s} {scenario:17s} {actions:9s} {imu:10s} {c.row_steps:9d} "
                              f"{c.exceptions:3d} {c.nonfinite:3d} {c.non_pd:5d} {c.flagged:7d}  "
                              f"{time.perf_counter() - t0:.1f} s", flush=True)
                        for e in c.errors:
                            print("   exception:", e)
                        totals[dtype] += c
    print(f"\ntotal ({time.perf_counter() - t_all:.0f} s wall)")
    print(f"{'dtype':7s} {'row-steps':>9s} {'exceptions':>10s} {'NaN/inf':>7s} {'non-PD':>6s} {'flagged':>7s}  reasons")
    for dtype, c in totals.items():
        reasons = "; ".join(f"{r}: {n}" for r, n in c.reasons.most_common())
        print(f"{dtype:7s} {c.row_steps:9d} {c.exceptions:10d} {c.nonfinite:7d} {c.non_pd:6d} {c.flagged:7d}  "
              f"{reasons or '-'}")
    ok = all(c.exceptions == c.nonfinite == c.non_pd == c.unexplained == 0 for c in totals.values())
    print("contract holds" if ok else "CONTRACT BROKEN")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
