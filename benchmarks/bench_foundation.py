"""Throughput of the foundation: world generation and the batched navigator.

Prints, side by side in one run:

* simulated IMU samples per second for truth + IMU + GNSS generation (and each part),
* navigator epochs per second (row-epochs: B rows x epochs / wall time) with ``kf``;
  one epoch = 100 IMU samples (mechanization + covariance propagation) + one
  tightly coupled update, at B = 1, 64, 256, 1024,
* where the navigator's time goes (fraction per stage) at the largest B.

Usage: ``python benchmarks/bench_foundation.py [--quick] [--dtype float32]``
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

from envs.episodes import navigator_for  # noqa: E402
from envs.sim.imu import IMU_GRADES, simulate_imu  # noqa: E402
from envs.sim.gnss import simulate_gnss  # noqa: E402
from envs.sim.rng import row_generators  # noqa: E402
from envs.sim.scenarios import get_scenario  # noqa: E402
from envs.sim.trajectory import generate_truth  # noqa: E402
from envs.sim.world import generate_world  # noqa: E402


def bench_generation(B, duration_s):
    scen = get_scenario("urban", duration_s=duration_s)
    seeds = list(range(B))
    t0 = time.perf_counter()
    motions = scen.motions(row_generators(seeds, "trajectory"))
    truth = generate_truth(motions, scen.duration_s, scen.imu_rate_hz)
    t1 = time.perf_counter()
    imu = simulate_imu(truth.f_b, truth.w_b, scen.imu_rate_hz, IMU_GRADES[scen.imu_grade], row_generators(seeds, "imu"),
                       engine_on=truth.engine_on, speed=truth.speed, vibration=scen.vibration)
    t2 = time.perf_counter()
    idx = np.arange(scen.samples_per_epoch, truth.t.size, scen.samples_per_epoch)
    at = truth.take(idx)
    simulate_gnss(truth.t[idx], at.r_e, at.v_e, at.heading, scen.constellation, scen.receiver, scen.events,
                  row_generators(seeds, "gnss"))
    t3 = time.perf_counter()
    n = B * truth.t.size
    return n, t1 - t0, t2 - t1, t3 - t2


def bench_navigator(B, epochs, dtype, profile=False):
    scen = get_scenario("open-sky", duration_s=float(epochs + 1))
    world = generate_world(scen, list(range(B)))
    nav = navigator_for(world, "kf", dtype=dtype)
    spe = scen.samples_per_epoch
    dt = 1.0 / scen.imu_rate_hz
    g = world.gnss
    stages = {"propagate": 0.0, "update": 0.0}
    warm = navigator_for(world, "kf", dtype=dtype)  # load the compiled kernel outside the timing
    warm.propagate_epoch(world.imu.f_b[:, 1:2], world.imu.w_b[:, 1:2], dt)
    t0 = time.perf_counter()
    k = 0
    for j in range(epochs):
        ta = time.perf_counter()
        nav.propagate_epoch(world.imu.f_b[:, k + 1:k + spe + 1], world.imu.w_b[:, k + 1:k + spe + 1], dt)
        k += spe
        tb = time.perf_counter()
        nav.update_gnss(g.sat_pos[:, j], g.sat_vel[:, j], g.pr[:, j], g.prr[:, j], g.pr_sigma[:, j], g.prr_sigma[:, j],
                        g.mask[:, j])
        tc = time.perf_counter()
        stages["propagate"] += tb - ta
        stages["update"] += tc - tb
    wall = time.perf_counter() - t0
    return B * epochs / wall, stages, wall


def profile_epoch(B, dtype, reps=3):
    """One 1 s epoch (100 IMU samples + update) at batch B, by stage, plus the numpy reference loop."""
    from nav_filters.error_model import system_matrix
    from nav_filters.ins import mechanize
    world = generate_world(get_scenario("open-sky", duration_s=3.0), list(range(B)))
    f, w = world.imu.f_b[:, 1:101], world.imu.w_b[:, 1:101]
    g = world.gnss
    out = {}
    for method in ("kf", "kf+onestep"):
        nav = navigator_for(world, method, dtype=dtype)
        nav.propagate_epoch(f, w, 0.01)  # compile / warm up
        nav.flush_prediction()
        t = time.perf_counter()
        for _ in range(reps):
            nav.propagate_epoch(f, w, 0.01)
        out[f"kernel: 100 samples, {'exact' if method == 'kf' else 'one-step (seed 001)'}"] = (time.perf_counter() - t) / reps
        t = time.perf_counter()
        for _ in range(reps):
            nav.flush_prediction()
            nav._pending = 1
        out[f"form.predict once ({method})"] = (time.perf_counter() - t) / reps
    t = time.perf_counter()
    for _ in range(reps):
        nav.update_gnss(g.sat_pos[:, 0], g.sat_vel[:, 0], g.pr[:, 0], g.prr[:, 0], g.pr_sigma[:, 0],
                        g.prr_sigma[:, 0], g.mask[:, 0])
    out["update_gnss (innovations + kf update + feedback)"] = (time.perf_counter() - t) / reps
    # numpy reference: what the kernel replaces, per-sample mechanize + F + dense P propagation
    r, v, C = world.init.r_e.copy(), world.init.v_e.copy(), world.init.C_eb.copy()
    P = np.broadcast_to(np.eye(17), (B, 17, 17)).copy()
    t = time.perf_counter()
    for k in range(100):
        F = system_matrix(C, f[:, k], r)
        Phi = np.eye(17) + 0.01 * F
        P = Phi @ P @ Phi.mT
        r, v, C = mechanize(r, v, C, f[:, k], w[:, k], 0.01)
    out["numpy reference: 100 x (mechanize + F + Phi P Phi^T)"] = time.perf_counter() - t
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes (a smoke run)")
    ap.add_argument("--dtype", default="float64", choices=("float64", "float32"))
    a = ap.parse_args()
    print(f"numpy {np.__version__}, {os.cpu_count()} CPUs, dtype {a.dtype}\n")
    print("World generation (urban scenario: truth + IMU + GNSS at 100 Hz / 1 Hz)")
    print(f"{'B':>6} {'duration':>9} {'samples':>10} {'truth/s':>12} {'imu/s':>12} {'gnss(epochs*B)/s':>17} {'total samples/s':>16}")
    for B, dur in ((1, 600.0), (64, 600.0), (256, 120.0), (1024, 60.0)) if not a.quick else ((1, 60.0), (64, 60.0)):
        n, tt, ti, tg = bench_generation(B, dur)
        print(f"{B:>6} {dur:>8.0f}s {n:>10d} {n / tt:>12.3g} {n / ti:>12.3g} {n / 100 / tg:>17.3g} {n / (tt + ti + tg):>16.3g}")
    print("\nNavigator, kf, 1 s epochs (100 IMU samples + 1 tightly coupled update)")
    print(f"{'B':>6} {'epochs':>7} {'row-epochs/s':>13} {'ms/epoch (batch)':>17} {'propagate %':>12} {'update %':>9}")
    sizes = ((1, 20), (64, 10), (256, 5), (1024, 3)) if not a.quick else ((1, 5), (64, 3))
    for B, E in sizes:
        rate, st, wall = bench_navigator(B, E, a.dtype)
        tot = st["propagate"] + st["update"]
        print(f"{B:>6} {E:>7} {rate:>13.4g} {1e3 * wall / E:>17.2f} {100 * st['propagate'] / tot:>12.1f} {100 * st['update'] / tot:>9.1f}")
    for Bp in (1, sizes[-1][0]):
        print(f"\nOne epoch at B = {Bp}, by stage (milliseconds):")
        for k, v in profile_epoch(Bp, a.dtype).items():
            print(f"  {k:<55s} {1e3 * v:10.3f}")


if __name__ == "__main__":
    main()
