"""Accuracy of the fast modes against the exact per-sample composition (the default), on every built-in
scenario, paired episodes.

Modes: ``averaged`` (``exact_transition=False``: the averaged-dynamics transition) and ``fused``
(``exact_transition=False, fused_update=True``: also the fused compiled update and the laws' fast kernels).
For each scenario of :func:`envs.worlds.scenario_names` (simulated and recorded) and each method, the same
world (same truth, same sensor errors) runs through :func:`envs.episodes.run_episodes` once per mode;
printed: horizontal RMSE of the exact run, and per fast mode the paired difference (fast minus exact) in %
of the exact RMSE with its paired-bootstrap 95% CI (:func:`envs.metrics.paired_difference`), and the
number of diverged episodes. The issue-11 bound is |difference| < 1% on every scenario.

Then the consistency check on a *matched* scenario (the filter's model is the truth's: open sky, tactical IMU
without scale-factor and misalignment errors, no vibration, no tropospheric / ionospheric residuals, as in
``tests/envs/test_navigation.py``): the ANEES of the 6 position/velocity states (ensemble mean at each
epoch after 10 s) of ``kf`` in every mode, against the 95% chi-square band of ``chi2(6 N) / N``.

Called by ``benchmarks/bench_envs.py --accuracy``.
"""
from __future__ import annotations

import time

import numpy as np

METHODS = ("sage-husa", "stkf", "ma-stkf")
"""The default method of each env id (GnssIns/SageHusa-v1, STKF-v0, MASTKF-v0)."""


def _scenario_duration(name, cap_s):
    """A simulated scenario's own length capped at ``cap_s``; None (the whole recording) for a data set."""
    from envs.sim.scenarios import SCENARIOS
    return min(cap_s, SCENARIOS[name].duration_s) if name in SCENARIOS else None


MODES = {"averaged": dict(exact_transition=False), "fused": dict(exact_transition=False, fused_update=True)}
"""The fast modes compared with the exact default: their navigator options."""


def accuracy_rows(scenarios=None, methods=METHODS, episodes=24, max_duration_s=700.0, seed=0, log=print,
                  modes=tuple(MODES)):
    """Paired comparison rows ``(scenario, method, duration_s, exact summary, {mode: (summary, paired)},
    {mode or 'exact': filter seconds})``."""
    from envs.episodes import run_episodes
    from envs.metrics import paired_difference, summarize
    from envs.worlds import make_world, scenario_names
    seeds = list(range(seed, seed + episodes))
    out = []
    for name in scenarios or scenario_names():
        dur = _scenario_duration(name, max_duration_s)
        try:
            world = make_world(name, seeds, duration_s=dur)
        except (ValueError, FileNotFoundError, OSError) as exc:  # a recorded data set not on this machine
            log(f"{name:26s} skipped: {exc}")
            continue
        for m in methods:
            t0 = time.perf_counter()
            exact = run_episodes(world, m)
            secs = {"exact": time.perf_counter() - t0}
            fast = {}
            for mode in modes:
                t0 = time.perf_counter()
                log_f = run_episodes(world, m, **MODES[mode])
                secs[mode] = time.perf_counter() - t0
                fast[mode] = (summarize(log_f), paired_difference(log_f, exact))
            row = (name, m, float(world.truth.t[-1] - world.truth.t[0]), summarize(exact), fast, secs)
            out.append(row)
            log(format_row(row))
    return out


def header(modes=tuple(MODES)):
    cols = "".join(f" {mode + ' RMSE':>13s} {'diff %':>8s} {'95% CI %':>18s}" for mode in modes)
    tag = "/".join(["e"] + [mode[0] for mode in modes])
    return (f"{'scenario':26s} {'method':9s} {'s':>5s} {'RMSE exact':>10s}{cols} {'div ' + tag:>9s} "
            f"{'filter s ' + tag:>16s}")


HEADER = header()


def format_row(row):
    name, m, dur, se, fast, secs = row
    ref = se["rmse_h_m"]
    cols = ""
    for sf, d in fast.values():
        lo, hi = (100 * c / ref for c in d["diff_rmse_h_ci95_m"])
        cols += f" {sf['rmse_h_m']:13.3f} {100 * d['rel_diff']:+8.3f} [{lo:+7.3f}, {hi:+7.3f}]"
    div = "/".join(str(x) for x in [se["diverged"]] + [sf["diverged"] for sf, _ in fast.values()])
    ts = "/".join(f"{t:.1f}" for t in secs.values())
    return f"{name:26s} {m:9s} {dur:5.0f} {ref:10.3f}{cols} {div:>9s} {ts:>16s}"


def matched_nees(n_runs=20, duration_s=120.0, method="kf", modes=tuple(MODES)):
    """ANEES (6 pos/vel states) of the exact and the fast modes on the matched scenario: ``{mode: (mean ANEES,
    fraction of epochs inside the band)}`` and the band ``(lo, hi)`` of chi2(6 N) / N."""
    from scipy.stats import chi2

    import envs.sim.imu as imu_mod
    from envs.episodes import run_episodes
    from envs.sim.gnss import ReceiverConfig
    from envs.sim.imu import IMU_GRADES, Vibration
    from envs.sim.scenarios import get_scenario
    from envs.sim.world import generate_world
    g = IMU_GRADES["tactical"].replace(name="matched", gyro_scale_sigma=0.0, accel_scale_sigma=0.0,
                                       gyro_misalignment_sigma=0.0, accel_misalignment_sigma=0.0)
    scen = get_scenario("open-sky", duration_s=duration_s, imu_grade="tactical", vibration=Vibration.none(),
                        receiver=ReceiverConfig(tropo_zenith_sigma_m=0.0, iono_zenith_sigma_m=0.0))
    lo, hi = chi2.ppf([0.025, 0.975], 6 * n_runs) / n_runs
    out = {}
    imu_mod.IMU_GRADES["matched-bench"] = g  # registered while the world and the filters use it
    try:
        world = generate_world(scen.replace(imu_grade="matched-bench"), list(range(n_runs)))
        for mode, kw in [("exact", {})] + [(mode, MODES[mode]) for mode in modes]:
            log = run_episodes(world, method, **kw)
            anees = np.mean(log.nees_pv[:, log.t >= 10.0], 0)
            out[mode] = (float(np.mean(anees)), float(np.mean((anees > lo) & (anees < hi))))
    finally:
        del imu_mod.IMU_GRADES["matched-bench"]
    return out, (float(lo), float(hi))


def print_accuracy(episodes=24, max_duration_s=700.0, methods=METHODS, scenarios=None, nees_runs=20,
                   modes=tuple(MODES)):
    """Print the accuracy table and the matched-scenario NEES (see the module docstring)."""
    print(f"\naccuracy of the fast modes vs the exact per-sample composition: averaged = exact_transition=False, "
          f"fused = exact_transition=False + fused_update=True;"
          f"\n{episodes} paired episodes (seeds 0..{episodes - 1}) per scenario, each scenario's own length up to "
          f"{max_duration_s:g} s; diff = fast - exact, % of the exact RMSE, paired bootstrap 95% CI")
    hdr = header(modes)
    print(hdr + "\n" + "-" * len(hdr))
    rows = accuracy_rows(scenarios, methods, episodes, max_duration_s, modes=modes)
    for mode in modes:
        worst = max(abs(r[4][mode][1]["rel_diff"]) for r in rows) if rows else float("nan")
        worst_ci = max(max(abs(c) for c in r[4][mode][1]["diff_rmse_h_ci95_m"]) / r[3]["rmse_h_m"]
                       for r in rows) if rows else 0
        print(f"{mode}: largest |diff| {100 * worst:.3f}%  (largest |CI bound|: {100 * worst_ci:.3f}%); issue-11 bound "
              f"1%: {'met' if worst < 0.01 else 'NOT met'} on all {len(rows)} scenario x method pairs")
    res, (lo, hi) = matched_nees(nees_runs, modes=modes)
    print(f"\nmatched scenario (open-sky, tactical IMU without scale/misalignment errors, no vibration, no tropo/"
          f"iono residuals), kf, {nees_runs} runs x 120 s: ANEES of pos/vel (6 dof), 95% band [{lo:.3f}, {hi:.3f}]")
    for mode, (m, frac) in res.items():
        print(f"  {mode:9s} mean ANEES {m:6.3f} ({'inside' if lo < m < hi else 'OUTSIDE'} the band), "
              f"{100 * frac:5.1f}% of epochs inside")
    return rows, res
