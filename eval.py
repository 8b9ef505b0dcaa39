"""Paired Monte Carlo comparison of navigation filters (DESIGN.md section 4).

Usage::

    python eval.py --scenario open-sky --methods kf --episodes 4 --seed 7 --out results/demo

Episode k of every method sees the same truth and the same sensor errors (the
world is generated once per scenario from the episode seeds and each method
runs on it). Prints a table and writes ``OUT/results.json`` plus
``OUT/results.csv``, ``OUT/results.md`` and ``OUT/error_vs_time_<scenario>.png``.

With no arguments it runs the default comparison: ``open-sky``, ``urban`` and
``outage`` with ``kf``, 8 episodes, seed 0, into ``results/default``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

DEFAULT_SCENARIOS = ("open-sky", "urban", "outage")
DEFAULT_METHODS = ("kf",)


def episode_seeds(seed: int, episodes: int) -> list[int]:
    """Seeds of the paired episodes: episode k gets ``seed * 1_000_003 + k``."""
    return [seed * 1_000_003 + k for k in range(episodes)]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="eval.py", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", action="append", metavar="NAME",
                   help=f"scenario name (repeatable); default: {', '.join(DEFAULT_SCENARIOS)}")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                   help="comma-separated filter methods (DESIGN.md section 4), e.g. kf,kf+onestep")
    p.add_argument("--episodes", type=int, default=8, help="Monte Carlo episodes per scenario (default 8)")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--batch-size", type=int, default=64, help="episodes run together in one batched navigator")
    p.add_argument("--dtype", choices=("float64", "float32"), default="float64", help="filter arithmetic")
    p.add_argument("--out", default="results/default", help="output directory (default results/default)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    return p


def fail(msg: str) -> "None":
    print(f"eval.py: error: {msg}", file=sys.stderr)
    raise SystemExit(2)


def main(argv=None) -> dict:
    args = build_parser().parse_args(argv)
    from envs.worlds import make_world, scenario_names
    from nav_filters.forms import parse_method

    scenarios = args.scenario or list(DEFAULT_SCENARIOS)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        fail("--methods is empty")
    for s in scenarios:
        if s not in scenario_names():
            fail(f"unknown scenario {s!r}; known: {', '.join(scenario_names())}")
    for m in methods:
        try:
            parse_method(m)
        except ValueError as e:
            fail(str(e))
    if args.episodes < 1:
        fail("--episodes must be >= 1")
    if args.batch_size < 1:
        fail("--batch-size must be >= 1")

    from envs.episodes import run_episodes
    from envs.metrics import summarize

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = episode_seeds(args.seed, args.episodes)
    results = {"scenarios": {}, "config": {"episodes": args.episodes, "seed": args.seed, "dtype": args.dtype,
                                           "methods": methods, "episode_seeds": seeds}}
    curves = {}
    for s in scenarios:
        logs = {m: [] for m in methods}
        t_start = time.perf_counter()
        for c0 in range(0, len(seeds), args.batch_size):
            chunk = seeds[c0:c0 + args.batch_size]
            try:
                world = make_world(s, chunk)
            except FileNotFoundError as e:
                fail(f"scenario {s!r} needs a recorded data set: {e}")
            for m in methods:
                done = c0 + len(chunk)
                print(f"\r[{s}] {m:<14s} episodes {c0 + 1}-{done}/{len(seeds)} ...", end="", flush=True, file=sys.stderr)
                logs[m].append(run_episodes(world, m, dtype=args.dtype))
        print(f"\r[{s}] done in {time.perf_counter() - t_start:.1f} s" + " " * 40, file=sys.stderr)
        results["scenarios"][s] = {}
        curves[s] = {}
        for m in methods:
            log = _concat(logs[m])
            results["scenarios"][s][m] = summarize(log)
            curves[s][m] = log
    (out / "results.json").write_text(json.dumps(results, indent=2))
    table = format_table(results)
    print(table)
    (out / "results.md").write_text(table + "\n")
    write_csv(results, out / "results.csv")
    if not args.no_plots:
        for s, per in curves.items():
            plot_error_vs_time(s, per, out / f"error_vs_time_{s}.png")
    print(f"wrote {out / 'results.json'}")
    return results


def _concat(logs):
    from envs.episodes import EpisodeLog
    if len(logs) == 1:
        return logs[0]
    kw = {}
    for f in EpisodeLog.__dataclass_fields__:
        vals = [getattr(l, f) for l in logs]
        if f == "t":
            kw[f] = vals[0]
        elif f == "filter_time_s":
            kw[f] = float(sum(vals))
        else:
            kw[f] = np.concatenate(vals, 0)
    return EpisodeLog(**kw)


COLUMNS = [("rmse_h_m", "RMSE h [m]"), ("rmse_h_ci95_m", "95% CI [m]"), ("rmse_3d_m", "RMSE 3D [m]"),
           ("p95_h_m", "p95 h [m]"), ("max_h_m", "max h [m]"), ("mean_nees_pv", "NEES pv"),
           ("filter_time_per_epoch_s", "ms/epoch"), ("diverged", "div")]


def _fmt(key, v):
    if key == "rmse_h_ci95_m":
        return f"{v[0]:.2f}-{v[1]:.2f}"
    if key == "filter_time_per_epoch_s":
        return f"{1e3 * v:.3f}"
    if key == "diverged":
        return str(v)
    return f"{v:.2f}"


def format_table(results: dict) -> str:
    """Markdown table of every scenario x method."""
    head = "| scenario | method | episodes | " + " | ".join(c[1] for c in COLUMNS) + " |"
    sep = "|" + "---|" * (3 + len(COLUMNS))
    rows = [head, sep]
    for s, per in results["scenarios"].items():
        for m, r in per.items():
            rows.append(f"| {s} | {m} | {r['episodes']} | " + " | ".join(_fmt(k, r[k]) for k, _ in COLUMNS) + " |")
    return "\n".join(rows)


def write_csv(results: dict, path: Path) -> None:
    keys = [k for k, _ in COLUMNS]
    lines = ["scenario,method,episodes," + ",".join(k if k != "rmse_h_ci95_m" else "rmse_h_ci95_lo_m,rmse_h_ci95_hi_m" for k in keys)]
    for s, per in results["scenarios"].items():
        for m, r in per.items():
            vals = []
            for k in keys:
                vals += [f"{r[k][0]:.6g}", f"{r[k][1]:.6g}"] if k == "rmse_h_ci95_m" else [f"{r[k]:.6g}"]
            lines.append(f"{s},{m},{r['episodes']}," + ",".join(vals))
    path.write_text("\n".join(lines) + "\n")


def plot_error_vs_time(scenario: str, logs: dict, path: Path) -> None:
    """Median and 10-90% band of the horizontal error vs time, one colour per method."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4), dpi=110)
    for m, log in logs.items():
        h = log.horizontal_error[~log.diverged]
        if h.size == 0:
            continue
        med = np.median(h, 0)
        lo, hi = np.quantile(h, [0.1, 0.9], axis=0)
        (line,) = ax.plot(log.t, med, label=f"{m} (median)")
        ax.fill_between(log.t, lo, hi, color=line.get_color(), alpha=0.2)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("horizontal position error [m]")
    ax.set_title(f"{scenario}: horizontal error, median and 10-90% band")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    main()
