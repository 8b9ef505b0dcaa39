"""Paired Monte Carlo comparison of navigation filters and tuning policies: every method runs on the same
episodes (the same truth and sensor errors), and each is compared with a reference method episode by
episode, with bootstrap 95% confidence intervals.

Usage::

    python eval.py --scenario urban --scenario noise-burst \\
                   --methods kf,sage-husa,stkf,ma-stkf,tuned:runs/x/tuning.json,ppo:runs/x/model.zip \\
                   --episodes 50 --seed 0 --out results/DIR [--reference kf] [--note docs/results.md]
    python eval.py --experiment seed000 --episodes 20 --out results/seed000

Method specs: a filter method (``kf``, ``svd-akf+onestep``, ...), an adaptive method with fixed parameters
(``sage-husa[b=0.995]``), the optimized fixed parameter (``tuned:<tuning.json>`` from ``train.py tune``),
a learned policy (``<algo>:<model.zip>`` from ``train.py rl``), or an oracle of an env's knob
(``oracle-schedule:<env id>``, ``best-per-episode:<env id>``, ``crossfit-schedule:<env id>``, options in
brackets: ``oracle-schedule:GnssIns/SageHusa-v1[segment_s=10,lookahead_s=20,n=7]``; see
:mod:`agents.methods`). Oracles know the truth: their rows are labelled ``oracle: ...`` and are never a
method a user could run. Episode k of every method sees the same truth and sensor errors (the worlds are
drawn from the episode seeds ``seed * 1_000_003 + k``).

``--headroom`` adds, per scenario, the optimized fixed parameter (the ``tuned:`` method, required) against
each oracle: headroom = (fixed - oracle) / fixed, the knob headroom net of the open-sky placebo (when
``open-sky`` is among the scenarios), the share of the (net) knob headroom every other method closed,
(fixed - method) / (fixed - oracle), and each oracle's headroom from the best hand-designed method of the
scenario (the lowest horizontal RMSE among the rows that are neither oracles nor learned policies: filters,
robust screens, adaptive laws, ``tuned:`` and ``rule:`` rows), (best - oracle) / best, with paired bootstrap
95% CIs (none below :data:`envs.metrics.MIN_CI_EPISODES` episodes). It prints the table and writes
``OUT/headroom.md`` and the ``"headroom"`` key of results.json (schema in :func:`compute_headroom`).

Prints a table and writes ``OUT/results.json`` (per scenario and method: episodes, horizontal RMSE and
its 95% CI, 3D RMSE, 95th percentile and maximum horizontal error, filter time per epoch, diverged
episodes, and the paired difference to the reference method), ``results.csv``, ``results.md`` and PNG plots per scenario (:mod:`plots`): error vs time
with the paired difference to the reference and the scenario's events, the trajectory of episode 0, the
parameter a learned policy set over time, the CDF of the horizontal error and each method's paired difference
to the reference with its 95% CI. Tables, plots and the note show short method labels (``tuned b=0.944``,
``ppo (3 seeds)``; :func:`method_labels`); results.json keeps the full specs (results.csv has both). The note
opens with one verdict per scenario and states what each tuned or learned method was trained on. The last line lists every file written.

``results.json`` is strict JSON (a NaN or inf figure is written as ``null``) and, apart from the wall-clock
figures named in :data:`TIMING_KEYS` (``filter_time_per_epoch_s`` of each method, part of the DESIGN.md
schema), a function of the arguments alone: two runs with the same arguments and seed write the same bytes
on every other line. The timings are also kept apart in ``OUT/timing.json`` (the run's wall time, per scenario
and each method's filter time per epoch); the ``ms/epoch`` column of ``results.md`` / ``results.csv``
shows the same figure.

``--backend ray`` runs the paired episode batches (one method on one chunk of ``--batch-size`` seeds) as Ray
tasks, on a local Ray started here (``--workers`` CPUs) or a cluster (``--address``); each batch generates
its world from its seeds where it runs and sends back the method's episode log: the same numbers as the
default ``--backend local`` (:mod:`agents.backends`, :mod:`agents.eval_batches`).

With no arguments it runs the default comparison: ``noise-burst``, ``urban`` and ``open-sky`` with ``kf``,
``sage-husa``, ``stkf`` and ``ma-stkf``, 8 episodes, seed 0, into ``results/default``.
"""
from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from agents.satellite_results import gap_share_text  # the gap table's cells (a stdlib-only module)

DEFAULT_SCENARIOS = ("noise-burst", "urban", "open-sky")
DEFAULT_METHODS = ("kf", "sage-husa", "stkf", "ma-stkf")


def episode_seeds(seed: int, episodes: int) -> list[int]:
    """Seeds of the paired episodes: episode k gets ``seed * 1_000_003 + k``."""
    return [seed * 1_000_003 + k for k in range(episodes)]


def build_parser() -> argparse.ArgumentParser:
    from cli_help import HelpFormatter, method_grammar
    p = argparse.ArgumentParser(prog="eval.py", description=__doc__.split("\n\n")[0], formatter_class=HelpFormatter,
                                epilog=method_grammar() + "\n\n" + __doc__.strip().split("\n\n")[-1].replace("``", ""))
    p.add_argument("--scenario", action="append", metavar="NAME",
                   help=f"scenario name or dataset spec path (*.toml; repeatable); default: "
                        f"{', '.join(DEFAULT_SCENARIOS)}")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                   help="comma-separated method specs (the grammar is below)")
    p.add_argument("--reference", default=None, help="method for the paired differences (default: the first)")
    p.add_argument("--skip-missing", action="store_true",
                   help="a file pattern of --methods ({scenario} or a glob) that matches no file on a scenario "
                        "leaves that method out there (listed on stdout, in results.json's config.skipped and in "
                        "the note) instead of stopping: for policies trained on some of the scenarios only; "
                        "the reference is never skipped")
    p.add_argument("--episodes", type=int, default=None,
                   help="Monte Carlo episodes per scenario (default 8; experiments: their own default)")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--batch-size", type=int, default=64, help="episodes run together in one batched navigator")
    p.add_argument("--dtype", choices=("float64", "float32"), default="float64", help="filter arithmetic")
    p.add_argument("--zupt", default="none", metavar="DETECTOR",
                   help="zero-velocity aiding for every method that names none: none (default), truth, shoe, are, "
                        "mag, mv, mlp, lstm (per method: 'kf[zupt=lstm]')")
    p.add_argument("--out", default="results/default", help="output directory (default results/default)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--note", default=None, metavar="PATH", help="also write a Markdown results note to PATH")
    p.add_argument("--goal", action="append", default=None, metavar="[SCENARIO=]PCT",
                   help="the note states whether each method's RMSE difference to the reference is at most PCT "
                        "percent: -20 asks for 20%% lower, 2 allows 2%% higher; SCENARIO= sets it for one "
                        "scenario (repeatable)")
    p.add_argument("--headroom", action="store_true",
                   help="also report the headroom: the optimized fixed parameter (a 'tuned:' method, required) "
                        "against each oracle, net of the open-sky placebo, the share of it each method "
                        "closed, and each oracle's headroom from the best hand-designed method of the scenario "
                        "(OUT/headroom.md, results.json 'headroom')")
    p.add_argument("--backend", default="local", choices=("local", "ray"),
                   help="where the paired episode batches run: local (this process, default) or ray (Ray tasks "
                        "on a local Ray started here, or on a cluster with --address); same numbers on both")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="--backend ray: join this Ray cluster ('auto' or HOST:6379 from 'ray start --head')")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="--backend ray: batches in flight at once (a local Ray gets N CPUs; default: all cores)")
    p.add_argument("--experiment", default=None, metavar="NAME",
                   help="run a seed-paper reproduction instead: seed000, seed001 or seed003 (its verdicts and "
                        "CIs only from 10 episodes, as the tables' CIs)")
    return p


TIMING_KEYS = ("filter_time_per_epoch_s",)
"""Keys of results.json that hold wall-clock figures (they differ between runs; everything else does not)."""


def fail(msg: str):
    print(f"eval.py: error: {msg}", file=sys.stderr)
    raise SystemExit(2)


_MADE: list = []
"""Output folders this run created (removed again when the run ends by an error or Ctrl-C and left them empty)."""


def check_out(out: Path, owner: str = "--out") -> None:
    """Create the output folder, or exit with one line when it cannot be written (before any work)."""
    from envs.outputs import check_output_dir
    existed = Path(out).exists()
    try:
        check_output_dir(out, owner)
    except ValueError as e:
        fail(str(e))
    if not existed:
        _MADE.append(Path(out))


def _headroom_fixed_spec(specs: list, scenarios: list, plan: dict) -> str:
    """The ``tuned:`` spec ``--headroom`` measures from: exactly one method on every scenario (one line otherwise)."""
    fixed_spec = next((sp for sp in specs if sp.startswith("tuned:")), None)
    if fixed_spec is None:
        fail("--headroom needs the optimized fixed parameter: add a 'tuned:<tuning.json>' method to --methods")
    for s in scenarios:
        if fixed_spec not in dict(plan[s]):
            fail(f"--headroom: {fixed_spec!r} matches no file on {s!r} (the optimized fixed parameter is "
                 "needed on every scenario)")
        n = len(dict(plan[s])[fixed_spec])
        if n != 1:
            fail(f"--headroom: {fixed_spec!r} must be one method; it matches {n} files on {s!r}")
    return fixed_spec


def check_note(path: Path) -> None:
    """``--note PATH`` before any work: one line when PATH is a folder or its folder cannot be created or
    written (a parent is a file, no permission); the folder is created (removed again if the run fails)."""
    if path.is_dir():
        fail(f"--note {str(path)!r} is a directory; give the note's file name (e.g. {str(path / 'results.md')!r})")
    check_out(path.parent, owner="--note's folder")


def _preflight(sources: dict, seeds: list) -> None:
    """Load every recorded scenario of ``sources`` ({result key: --scenario value}) once before any work, its
    world for the first batch's ``seeds`` (kept for that batch, :func:`agents.eval_batches.world_for`): a data
    problem (a damaged or implausible file, truth that does not overlap the observations, ...) is one line
    naming the file, not a traceback after the simulated scenarios ran."""
    from agents.eval_batches import world_for
    from envs.datasets.spec import dataset_spec_of
    for key, src in sources.items():
        try:
            if dataset_spec_of(src) is None:
                continue
            world_for(src, seeds)
        except FileNotFoundError as e:  # world_for names the scenario
            fail(str(e))
        except ValueError as e:
            fail(f"scenario {key!r}: {e}")


def _split_methods(text: str) -> list[str]:
    """Split on commas outside brackets (``sage-husa[b=0.99,x=1],kf``)."""
    out, depth, cur = [], 0, ""
    for ch in text:
        depth += ch == "["
        depth -= ch == "]"
        if ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
        else:
            cur += ch
    if cur.strip():
        out.append(cur.strip())
    return out


def _scenario_key(s: str, names) -> str:
    """The result key of a ``--scenario`` value: a known name itself, a dataset spec (``*.toml``) its ``name``;
    exits with a one-line error for an unknown name or a bad spec."""
    from envs.datasets.spec import is_spec_path, load_dataset_spec
    if is_spec_path(s):
        try:
            return load_dataset_spec(s).name
        except (ValueError, FileNotFoundError) as e:
            fail(str(e))
    if s not in names:
        fail(f"unknown scenario {s!r}; known: {', '.join(names)}, or a dataset spec path (*.toml)")
    return s


def _expand(specs: list[str], scenario: str, ref: str, skipped: list | None = None) -> list:
    """[(spec, [methods])] of ``specs`` on ``scenario`` (``{scenario}`` and glob patterns expanded); exits
    with a one-line error for a bad spec, a reference that is not one method, or a label given twice.

    With ``skipped`` (a list; ``--skip-missing``) a spec whose file pattern matches nothing on ``scenario`` is
    left out and ``{"scenario", "method", "why"}`` appended to ``skipped``; the reference never is."""
    from agents.methods import expand_method_spec
    plan, seen = [], set()
    for spec in specs:
        try:
            ms = expand_method_spec(spec, scenario)
        except FileNotFoundError as e:
            if skipped is None or spec == ref:
                fail(str(e))
            skipped.append({"scenario": scenario, "method": spec, "why": str(e)})
            print(f"skipped on {scenario}: {spec} ({e})", file=sys.stderr)
            continue
        except ValueError as e:
            fail(str(e))
        if spec == ref and len(ms) != 1:
            fail(f"--reference {ref!r} must be one method; it matches {len(ms)} files on {scenario!r}")
        for m in ms:
            if m.label in seen:
                fail(f"method {m.label!r} is given twice in --methods")
            seen.add(m.label)
        plan.append((spec, ms))
    return plan


def main(argv=None) -> dict:
    """The command line (module docstring); returns results.json's dict. Ctrl-C ends it with one line and exit
    status 130; an output folder this run created and left empty is removed (after an error too)."""
    from envs.outputs import remove_if_empty
    _MADE.clear()
    try:
        return _main(argv)
    except KeyboardInterrupt:
        gone = [d for d in _MADE if remove_if_empty(d)]
        left = [d for d in _MADE if d not in gone and d.is_dir()]
        print("eval.py: interrupted (Ctrl-C)" + (f"; {', '.join(map(str, left))} holds only the files written "
                                                 "before it" if left else "; no results written"), file=sys.stderr)
        raise SystemExit(130) from None
    except BaseException:
        for d in _MADE:
            remove_if_empty(d)
        raise


def _check_run_args(args) -> None:
    """One clear line (:func:`fail`) for a count, seed or backend argument out of its range."""
    if args.episodes is not None and args.episodes < 1:
        fail("--episodes must be >= 1")
    if args.batch_size < 1:
        fail("--batch-size must be >= 1")
    if args.seed < 0 or (args.seed + 1) * 1_000_003 >= 2**30:
        fail("--seed must be in 0..1072 (episode seeds stay below the environments' training seeds, 2**30)")
    from agents.backends import BackendUnavailable, check_backend_args
    try:
        check_backend_args(args.backend, args.address, args.workers)
    except (ValueError, BackendUnavailable) as e:
        fail(str(e))
    if args.experiment and args.backend != "local":
        fail("--backend ray runs the paired comparison's batches; --experiment runs here only (drop --backend)")


def _main(argv=None) -> dict:
    args = build_parser().parse_args(argv)
    _check_run_args(args)
    out = Path(args.out)
    if args.experiment:
        return run_experiment_cli(args, out)
    if args.episodes is None:
        args.episodes = 8
    from envs.worlds import scenario_names

    scenarios = args.scenario or list(DEFAULT_SCENARIOS)
    specs = _split_methods(args.methods)
    if not specs:
        fail("--methods is empty")
    sources = {}  # result key (the scenario name; a spec's own name) -> what make_world is given
    for s in scenarios:
        key = _scenario_key(s, scenario_names())
        if key in sources:
            fail(f"scenario {key!r} is given twice in --scenario")
        sources[key] = s
    scenarios = list(sources)
    from envs.zupt_source import check_zupt_choice
    try:
        check_zupt_choice(args.zupt, owner="--zupt")
    except ValueError as e:
        fail(str(e))
    ref = args.reference or specs[0]
    if ref not in specs:
        fail(f"--reference {ref!r} is not one of --methods")
    skipped = [] if args.skip_missing else None
    plan = {s: _expand(specs, s, ref, skipped) for s in scenarios}  # scenario -> [(spec, [methods])]
    from agents.methods import is_oracle_label
    first = scenarios[0]
    if any(is_oracle_label(m.label) for m in dict(plan[first])[ref]):
        fail(f"--reference {ref!r} is an oracle; the reference must be a method a user could run")
    if args.zupt not in ("none", "truth") and any(getattr(m, "is_oracle", False)
                                                  for _, ms in plan[first] for m in ms):
        fail(f"the oracle methods branch the filter state, which the {args.zupt!r} detector's stream state does "
             "not allow: use --zupt none or truth")
    fixed_spec = _headroom_fixed_spec(specs, scenarios, plan) if args.headroom else None

    from envs.json_io import dumps
    from envs.metrics import paired_difference, summarize, summarize_seeds
    from envs.outputs import write_atomic

    seeds = episode_seeds(args.seed, args.episodes)
    _preflight(sources, seeds[:args.batch_size])
    if args.note:
        check_note(Path(args.note))
    check_out(out)
    results = {"scenarios": {}, "seed_groups": {},
               "config": {"episodes": args.episodes, "seed": args.seed, "dtype": args.dtype, "zupt": args.zupt,
                          "goal": _parse_goals(args.goal),
                          "methods": specs, "reference": ref, "episode_seeds": seeds,
                          **({"skipped": skipped} if skipped else {})}}
    timing = {"note": "wall-clock figures of this run (they vary between runs; results.json holds the rest)"}
    for s in scenarios:
        results["config"].setdefault("reference_labels", {})[s] = dict(plan[s])[ref][0].label
    from earth.numba_cache import announce_compilation
    announce_compilation()  # a first run compiles the kernels for minutes: one line says so
    t_start = time.perf_counter()
    by_source, track_by_source, events_by_source, length_by_source = run_batches(
        args, {sources[s]: [m for _, ms in plan[s] for m in ms] for s in scenarios}, seeds)
    timing["wall_time_s"] = time.perf_counter() - t_start
    curves = {s: by_source[sources[s]] for s in scenarios}
    tracks = {s: track_by_source[sources[s]] for s in scenarios if sources[s] in track_by_source}
    events = {s: events_by_source.get(sources[s], []) for s in scenarios}
    for s in scenarios:
        if sources[s] in length_by_source:
            results["config"].setdefault("episode_length_s", {})[s] = length_by_source[sources[s]]
    for s in scenarios:
        ref_label = results["config"]["reference_labels"][s]
        results["scenarios"][s] = {label: summarize(log) for label, log in curves[s].items()}
        for label in curves[s]:
            if is_oracle_label(label):
                results["scenarios"][s][label]["oracle"] = True
        for label, log in curves[s].items():
            if label != ref_label:
                results["scenarios"][s][label]["paired_vs_reference"] = paired_difference(log, curves[s][ref_label])
        groups = {spec: ms for spec, ms in plan[s] if len(ms) > 1}
        if groups:
            results["seed_groups"][s] = {
                spec: {"members": [m.label for m in ms],
                       **summarize_seeds([curves[s][m.label] for m in ms], curves[s][ref_label])}
                for spec, ms in groups.items()}
    if args.headroom:
        results["headroom"] = compute_headroom(results, curves, plan, fixed_spec)
    gap = compute_gap_to_oracle_r(results, curves, plan)
    if gap:
        results["gap_to_oracle_r"] = gap
    write_atomic(out / "results.json", dumps(results, indent=2) + "\n")
    timing["scenarios"] = {s: {"methods": {label: {k: r[k] for k in TIMING_KEYS if k in r} for label, r in per.items()}}
                           for s, per in results["scenarios"].items()}
    write_atomic(out / "timing.json", dumps(timing, indent=2) + "\n")
    table = format_table(results)
    print(table)
    write_atomic(out / "results.md", table + "\n")
    if gap:
        print("\nShare of the gap from the reference to oracle-r closed\n\n"
              + format_gap_to_oracle_r(gap, {s: method_labels(results, s) for s in gap}))
    if args.headroom:
        htable = format_headroom(results["headroom"], {s: method_labels(results, s) for s in results["scenarios"]})
        print("\nHeadroom\n\n" + htable)
        write_atomic(out / "headroom.md", htable + "\n")
    write_csv(results, out / "results.csv")
    plots = [] if args.no_plots else write_all_plots(out, results, curves, tracks, events, plan)
    written = [out / "results.json", out / "timing.json", out / "results.md", out / "results.csv"]
    if args.headroom:
        written.append(out / "headroom.md")
    written += plots
    if args.note:
        write_note(results, Path(args.note), out, shlex.join(sys.argv[1:] if argv is None else argv))
        written.append(Path(args.note))
    print("wrote " + ", ".join(str(p) for p in written))
    return results


def write_all_plots(out: Path, results: dict, curves: dict, tracks: dict, events: dict, plan: dict) -> list:
    """The PNGs of every scenario (:mod:`plots`, short labels of :func:`method_labels`); their paths."""
    import plots
    from agents.methods import PolicyMethod
    paths = []
    for s, per in curves.items():
        masks = events.get(s, [])  # a recording has no event mask (None): nothing to shade
        ev = np.concatenate(masks, 0) if masks and all(m is not None for m in masks) else None
        ev = ev if ev is not None and ev.shape[-1] == next(iter(per.values())).t.size else None
        learned = [m.label for _, ms in plan[s] for m in ms if isinstance(m, PolicyMethod)]
        pooled = {pooled_key(spec, g): g for spec, g in _group_rows(results, s)}
        paths += plots.write_plots(out, s, per, results["scenarios"][s], _ref_label(results, s),
                                   method_labels(results, s), tracks[s], ev, learned, pooled=pooled)
    return paths


def run_experiment_cli(args, out: Path) -> dict:
    try:
        from experiments import EXPERIMENTS, run_experiment
    except ImportError as e:  # pragma: no cover
        fail(f"experiments are not available: {e}")
    if args.experiment not in EXPERIMENTS:
        fail(f"unknown experiment {args.experiment!r}; known: {', '.join(EXPERIMENTS)}")
    check_out(out)
    from earth.numba_cache import announce_compilation
    announce_compilation()
    res, report = run_experiment(args.experiment, episodes=args.episodes, seed=args.seed, out_dir=out,
                                 progress=lambda msg: print(msg, file=sys.stderr))
    print(report)
    print(f"wrote {out / (args.experiment + '.md')} and {out / (args.experiment + '.json')}")
    return res


def run_batches(args, methods_by_scenario: dict, seeds: list[int]) -> tuple[dict, dict, dict, dict]:
    """Run every (scenario, chunk, method) batch on ``args.backend``: ``({scenario: {label: EpisodeLog}},
    {scenario: (M, 2) truth track of episode 0}, {scenario: [event mask of each chunk]},
    {scenario: episode length [s]})`` (:mod:`agents.eval_batches`, :mod:`agents.backends`)."""
    from agents.backends import BackendUnavailable, make_backend
    from envs.datasets.errors import DatasetFormatError
    from agents.eval_batches import clear_world_cache, gather, gather_context, plan_batches, run_eval_batch
    batches = plan_batches(methods_by_scenario, seeds, args.batch_size, args.dtype, args.zupt)
    t0 = time.perf_counter()
    try:
        with make_backend(args.backend, args.address, args.workers) as backend:
            done = backend.map(run_eval_batch, batches, desc=f"eval ({args.backend})", label=lambda b: b.describe())
    except (FileNotFoundError, BackendUnavailable, DatasetFormatError) as e:
        fail(str(e))
    finally:
        clear_world_cache()
    n_methods = sum(len(ms) for ms in methods_by_scenario.values())
    print(f"{n_methods} (scenario, method) pairs x {len(seeds)} episodes in {len(batches)} batches on {args.backend} "
          f"in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return (*gather(batches, done), *gather_context(batches, done))


COLUMNS = [("rmse_h_m", "RMSE h [m]"), ("rmse_h_ci95_m", "95% CI [m]"), ("rmse_3d_m", "RMSE 3D [m]"),
           ("p95_h_m", "p95 h [m]"), ("max_h_m", "max h [m]"), ("excluded_per_epoch", "excl/epoch"),
           ("filter_time_per_epoch_s", "ms/epoch"), ("diverged", "div")]
"""The table's metric columns; ``excl/epoch`` (measurement rows excluded per epoch) is ``-`` for a method that
never excludes."""


def _fmt(key, v):
    if v is None:
        return "-"
    if key == "rmse_h_ci95_m":
        return f"{v[0]:.2f}-{v[1]:.2f}"
    if key == "filter_time_per_epoch_s":
        return f"{1e3 * v:.3f}"
    if key == "diverged":
        return str(v)
    return f"{v:.2f}"


def _fmt_pair(r):
    from envs.metrics import MIN_CI_EPISODES, no_ci_text
    p = r.get("paired_vs_reference")
    if not p:
        return "(reference)"
    if p["episodes"] < MIN_CI_EPISODES:
        return f"{p['diff_rmse_h_m']:+.2f} ({100 * p['rel_diff']:+.1f}%; {no_ci_text()})"
    lo, hi = p["diff_rmse_h_ci95_m"]
    return f"{p['diff_rmse_h_m']:+.2f} [{lo:+.2f}, {hi:+.2f}] ({100 * p['rel_diff']:+.1f}%)"


def pooled_key(spec: str, g: dict) -> str:
    """The label of the pooled row of the seed group of ``spec`` (``g``: its ``seed_groups`` entry), as the
    headroom section names it."""
    return f"{spec} (pooled over {g['seeds']} seeds)"


def _group_rows(results: dict, s: str):
    """(spec, pooled metrics) of the seed groups of scenario ``s``."""
    yield from results.get("seed_groups", {}).get(s, {}).items()


def method_labels(results: dict, s: str) -> dict:
    """``{row label: short label}`` of scenario ``s``: its methods (:func:`agents.provenance.short_labels`,
    distinct) and the pooled rows of its seed groups (:func:`pooled_key` -> ``'ppo (3 seeds)'``). The tables,
    the note and the plots show these; results.json keeps the full specs."""
    from agents.provenance import short_label, short_labels
    out = short_labels(list(results["scenarios"][s]), s)
    for spec, g in _group_rows(results, s):
        out[pooled_key(spec, g)] = short_label(spec, s, g["seeds"])
    return out


def _table_rows(results: dict, s: str):
    """(short label, metrics) of every row of scenario ``s``: the methods, then the pooled rows (their per-seed
    RMSE range in the label)."""
    lab = method_labels(results, s)
    for m, r in results["scenarios"][s].items():
        yield lab[m], r
    for spec, g in _group_rows(results, s):
        lo, hi = min(g["rmse_h_per_seed_m"]), max(g["rmse_h_per_seed_m"])
        yield f"{lab[pooled_key(spec, g)]}, pooled (per seed {lo:.2f}-{hi:.2f} m)", g


def format_table(results: dict) -> str:
    """Markdown table of every scenario x method (short labels, :func:`method_labels`), with the paired
    difference to the reference; a method given as a pattern over training seeds also gets a pooled row
    (:func:`envs.metrics.summarize_seeds`). Below :data:`envs.metrics.MIN_CI_EPISODES` episodes the CI columns
    say so instead of a CI."""
    from envs.metrics import MIN_CI_EPISODES, no_ci_text
    head = ("| scenario | method | episodes | " + " | ".join(c[1] for c in COLUMNS)
            + " | vs the reference: dRMSE h [m] (95% CI) |")
    sep = "|" + "---|" * (4 + len(COLUMNS))
    rows = [head, sep]
    for s in results["scenarios"]:
        for m, r in _table_rows(results, s):
            few = r["episodes"] < MIN_CI_EPISODES
            rows.append(f"| {s} | {m} | {r['episodes']} | " + " | ".join(
                no_ci_text() if few and k == "rmse_h_ci95_m" else _fmt(k, r.get(k)) for k, _ in COLUMNS)
                        + f" | {_fmt_pair(r)} |")
    return "\n".join(rows)


def write_csv(results: dict, path: Path) -> None:
    keys = [k for k, _ in COLUMNS]
    lines = ["scenario,method,label,episodes," + ",".join(
        k if k != "rmse_h_ci95_m" else "rmse_h_ci95_lo_m,rmse_h_ci95_hi_m" for k in keys)
        + ",diff_rmse_h_m,diff_lo_m,diff_hi_m"]
    for s, per in results["scenarios"].items():
        lab = method_labels(results, s)
        pooled = [(pooled_key(spec, g), g) for spec, g in _group_rows(results, s)]
        for m, r in list(per.items()) + pooled:
            vals = []
            for k in keys:
                if k == "rmse_h_ci95_m":
                    vals += [f"{r[k][0]:.6g}", f"{r[k][1]:.6g}"]
                else:
                    vals.append("" if r.get(k) is None else f"{r[k]:.6g}")  # (a method that never excludes)
            p = r.get("paired_vs_reference")
            vals += ([f"{p['diff_rmse_h_m']:.6g}", f"{p['diff_rmse_h_ci95_m'][0]:.6g}",
                      f"{p['diff_rmse_h_ci95_m'][1]:.6g}"] if p else ["0", "0", "0"])
            lines.append(f"\"{s}\",\"{m}\",\"{lab[m]}\",{r['episodes']}," + ",".join(vals))
    from envs.outputs import write_atomic
    write_atomic(path, "\n".join(lines) + "\n")


def _verdict(p: dict) -> str:
    from envs.metrics import no_ci_text, paired_verdict
    return {"no CI": no_ci_text(), "lower": "lower (the 95% CI excludes 0)",
            "higher": "higher (the 95% CI excludes 0)",
            "not significant": "no significant difference (the 95% CI includes 0)"}[paired_verdict(p)]


def _compared_rows(results: dict, s: str) -> list:
    """(row label, metrics) of the methods of scenario ``s`` compared with the reference: the pooled row of
    a seed group in place of its members, every other row with a paired difference (oracles included)."""
    members = {m for _, g in _group_rows(results, s) for m in g.get("members", [])}
    rows = [(m, r) for m, r in results["scenarios"][s].items() if "paired_vs_reference" in r and m not in members]
    return rows + [(pooled_key(spec, g), g) for spec, g in _group_rows(results, s)]


def verdict_sentence(results: dict, s: str) -> str:
    """The note's opening sentence on scenario ``s``: the best method a user could run (no oracle) and its
    paired difference to the reference with the 95% CI, whether any method is significantly better, or that
    there is no verdict below :data:`envs.metrics.MIN_CI_EPISODES` episodes."""
    from agents.methods import is_oracle_label
    from envs.metrics import MIN_CI_EPISODES, paired_verdict
    lab = method_labels(results, s)
    ref = _ref_label(results, s)
    ref_rmse = results["scenarios"][s].get(ref, {}).get("rmse_h_m")
    cands = [(m, r["paired_vs_reference"]) for m, r in _compared_rows(results, s)
             if not is_oracle_label(m) and r["paired_vs_reference"]["episodes"] > 0
             and np.isfinite(r["paired_vs_reference"]["diff_rmse_h_m"])]
    head = f"`{s}` ({results['config']['episodes']} episodes, reference `{lab.get(ref, ref)}`"
    head += f" {ref_rmse:.2f} m)" if ref_rmse is not None and np.isfinite(ref_rmse) else ")"
    if not cands:
        return f"{head}: no other method to compare."
    m, p = min(cands, key=lambda c: c[1]["diff_rmse_h_m"])
    d = p["diff_rmse_h_m"]
    diff = f"`{lab[m]}`, {d:+.3f} m" if abs(d) < 0.01 else f"`{lab[m]}`, {d:+.2f} m"
    diff += f", {100 * p['rel_diff']:+.1f}%"
    if p["episodes"] < MIN_CI_EPISODES:
        lowest = f"the reference; the closest: {diff}" if p["diff_rmse_h_m"] >= 0 else f"{diff} against the reference"
        return f"{head}: no verdict below {MIN_CI_EPISODES} episodes (lowest RMSE: {lowest}; no CI)."
    lo, hi = p["diff_rmse_h_ci95_m"]
    ci = f"95% CI [{lo:+.2f}, {hi:+.2f}] m"
    if p["diff_rmse_h_m"] >= 0:
        return f"{head}: the reference is best (the closest: {diff}, {ci})."
    if paired_verdict(p) == "lower":
        return f"{head}: best is {diff} against the reference ({ci}): significantly lower."
    return f"{head}: no method is significantly better than the reference (lowest RMSE: {diff}, {ci})."


def _parse_goals(items) -> dict | None:
    """``--goal`` values -> ``{scenario or '*': relative difference}`` (None without any)."""
    if not items:
        return None
    goals = {}
    for item in items:
        scen, _, pct = item.rpartition("=")
        try:
            goals[scen or "*"] = float(pct) / 100.0
        except ValueError:
            fail(f"--goal expects [SCENARIO=]PCT, got {item!r}")
    return goals


def reading(results: dict, goals: dict | None = None) -> list[str]:
    """Sentences computed from the results: each method against the reference (and its ``goals``,
    ``{scenario or '*': max relative difference}``), and each tuned parameter's search (from its tuning
    file): how much the whole parameter range moved the training RMSE. Where methods were given as patterns
    over training seeds, only their pooled rows are read (the table has the rest); methods are named by their
    short labels (:func:`method_labels`)."""
    from envs.metrics import MIN_CI_EPISODES
    c = results["config"]
    out = []
    for s in results["scenarios"]:
        goal_rel = None if not goals else goals.get(s, goals.get("*"))
        lab = method_labels(results, s)
        ref = _ref_label(results, s)
        ref_rmse = results["scenarios"][s].get(ref, {}).get("rmse_h_m", float("nan"))
        rows = _compared_rows(results, s)
        pooled = [(m, r) for m, r in rows if "seeds" in r]
        for m, r in pooled or rows:  # a pattern over training seeds: the note reads its pooled rows
            p = r["paired_vs_reference"]
            lo, hi = p["diff_rmse_h_ci95_m"]
            few = p["episodes"] < MIN_CI_EPISODES
            ci = "" if few else f", 95% CI [{lo:+.2f}, {hi:+.2f}] m"
            if goal_rel is None or m.startswith("oracle"):
                tail = "."
            elif few:
                tail = f"; goal {100 * goal_rel:+.0f}% not judged (n < {MIN_CI_EPISODES})."
            else:
                tail = f"; goal {100 * goal_rel:+.0f}% {'met' if p['rel_diff'] <= goal_rel else 'not met'}."
            out.append(f"- `{s}`: {lab[m]}: horizontal RMSE {100 * p['rel_diff']:+.1f}% against "
                       f"`{lab.get(ref, ref)}` ({p['diff_rmse_h_m']:+.2f} m{ci}; reference {ref_rmse:.2f} m): "
                       f"{_verdict(p)}{tail}")
    for spec in c["methods"]:
        if not spec.startswith("tuned:"):
            continue
        used: dict = {}   # tuning file -> scenarios it was used on
        for s in results["scenarios"]:
            used.setdefault(spec.split(":", 1)[1].replace("{scenario}", s), []).append(s)
        for path, scens in used.items():
            try:
                t = json.loads(Path(path).read_text())
            except (OSError, ValueError):
                continue
            r = [x for x in t.get("rmse_h_m", []) if x == x]
            if not r:
                continue
            grid = t["grid"]
            edge = " (at the edge of the searched range)" if t["best"] in (grid[0], grid[-1]) else ""
            where = ", ".join(f"`{x}`" for x in scens)
            out.append(f"- {where}: the optimized fixed {t['param']} = {t['best']:.4g} (`{path}`){edge}; over the "
                       f"searched {t['param']} in [{grid[0]:.4g}, {grid[-1]:.4g}] the training RMSE spans "
                       f"{min(r):.3f}-{max(r):.3f} m ({100 * (max(r) / min(r) - 1):.1f}% above the best at worst).")
    return out


PLACEBO_SCENARIO = "open-sky"
"""The scenario without events: a hindsight oracle's headroom there is luck (the placebo)."""
HEADROOM_INTRO = ("Headroom = (optimized fixed - oracle) / optimized fixed, from the pooled horizontal RMSEs of "
                  "the paired episodes; the knob oracle's (`oracle-schedule`) net of the open-sky placebo (its "
                  "headroom on open-sky subtracted) where open-sky was run. Share closed = (fixed - method) / "
                  "(fixed - oracle) of the (net) knob headroom. Headroom from the best hand-designed = (best - "
                  "oracle) / best, where best is the scenario's row with the lowest horizontal RMSE among the "
                  "methods that are neither oracles nor learned policies (filters, robust screens, adaptive "
                  "laws, tuned fixed parameters, hand-designed rules; not net of the placebo). Paired bootstrap "
                  "95% CIs over episodes (the placebo's episodes resampled independently). Oracles know the "
                  "truth: they bound what a policy could reach, they are not methods a user could run.")


GAP_INTRO = ("Share of the gap closed = (reference - method) / (reference - oracle-r), from the pooled horizontal "
             "RMSEs of the paired episodes (oracle-r: the filter given the simulator's true variance of every "
             "satellite and epoch, the floor of the per-satellite action space): 1 reaches the oracle, 0 the "
             "reference, below 0 worse than the reference. Paired bootstrap 95% CIs over episodes; none where the "
             "gap's own CI includes 0.")


def _oracle_kind(label: str) -> str:
    """``'oracle-schedule'``, ``'best-per-episode'``, ``'crossfit-schedule'``, ``'oracle-r'`` (the R oracle)."""
    if label.startswith("oracle-r"):
        return "oracle-r"
    return label.removeprefix("oracle: ").split(":", 1)[0]


def _episode_mse(log):
    """``(per-episode MSE, excluded)`` of one method's log: excluded where it diverged or the MSE is not finite."""
    from envs.metrics import episode_mse
    a = episode_mse(log)
    return a, log.diverged | ~np.isfinite(a)


def _compared_mse_rows(results: dict, per: dict, plan_s: list, s: str, base_label: str) -> list:
    """The rows a headroom or gap table compares with its base: every method of scenario ``s`` that is neither an
    oracle nor ``base_label``, and the pooled row of each seed group (the mean of its members' per-episode MSEs,
    excluded where any member is). Items ``(label, mse (E,), excluded (E,), learned, pooled, rmse_h_m)``."""
    from agents.methods import PolicyMethod, is_oracle_label
    rows = []
    for spec, ms in plan_s:
        live = [m for m in ms if not is_oracle_label(m.label) and m.label != base_label]
        rows += [(m.label, *_episode_mse(per[m.label]), isinstance(m, PolicyMethod), False,
                  results["scenarios"][s][m.label]["rmse_h_m"]) for m in live]
        if len(live) > 1:
            parts = [_episode_mse(per[m.label]) for m in live]
            rows.append((f"{spec} (pooled over {len(live)} seeds)", np.mean([p[0] for p in parts], 0),
                         np.any([p[1] for p in parts], 0), isinstance(live[0], PolicyMethod), True,
                         results["seed_groups"][s][spec]["rmse_h_m"]))
    return rows


def compute_headroom(results: dict, curves: dict, plan: dict, fixed_spec: str) -> dict:
    """The ``"headroom"`` section of results.json.

    Schema (RMSEs in metres, headrooms and shares as fractions, CIs ``[lo, hi]`` or null below
    ``min_ci_episodes``)::

        {"min_ci_episodes": 10, "fixed": "<tuned: spec>", "placebo": "open-sky" or null,
         "scenarios": {"<scenario>": {
            "note": "placebo: open-sky" | "placebo not measured ..." | "this is the placebo scenario ...",
            "fixed": {"label", "rmse_h_m", "episodes"},
            "knob_oracle": "<label of the oracle-schedule row>" or null,
            "best_hand_designed": {"label", "rmse_h_m", "episodes", "diverged", "candidates": [labels]} or null,
            "oracles": {"<label>": {"kind", "rmse_h_m", "episodes", "headroom", "headroom_ci95",
                                    "placebo_headroom", "placebo_episodes", "net_headroom",
                                    "net_headroom_ci95", "ci_note",
                                    "from_best": {"episodes", "headroom", "headroom_ci95", "ci_note"}}},
            "methods": {"<label>": {"learned", "pooled", "rmse_h_m", "episodes", "share", "share_ci95",
                                    "gap_m", "gap_ci95_m", "net", "note"}}}}}

    ``oracles`` has every oracle row (labels ``oracle...``; ``kind`` from :func:`_oracle_kind`), its
    headroom over the fixed parameter and, where the placebo was run (and this is not it), net of the same
    oracle's placebo headroom. ``methods`` has every other method (learned ``<algo>:`` rows, each training
    seed and the pooled row of a seed group, and the filters) with the share of the knob oracle's (net)
    headroom it closed (:func:`envs.metrics.headroom_share`; on the placebo scenario itself the gross
    headroom). Episodes where a compared method diverged leave that comparison.

    ``best_hand_designed`` is the scenario's best hand-designed method (:func:`best_hand_designed`): of the
    ``candidates``, every method row that is neither an oracle nor a learned policy (filters, robust screens,
    adaptive laws, ``tuned:`` fixed parameters, each member of a seed group of them, ``rule:`` rows), the one
    with the lowest pooled horizontal RMSE of the results table (``rmse_h_m``: diverged episodes left out and
    counted in ``diverged``, as :func:`envs.metrics.summarize` does); null when none has a finite RMSE. Each
    oracle's ``from_best`` is :func:`envs.metrics.headroom` from that method to the oracle, ``(R_best -
    R_oracle) / R_best`` over the episodes where neither diverged, gross (no placebo), with its CI only from
    ``min_ci_episodes`` episodes (``ci_note`` says so below). ``headroom`` beside it stays the headroom over
    the optimized fixed parameter.
    """
    from agents.methods import is_oracle_label
    from envs.metrics import MIN_CI_EPISODES, headroom, headroom_share

    placebo = PLACEBO_SCENARIO if PLACEBO_SCENARIO in curves else None
    mse = _episode_mse

    def fixed_of(s):
        return mse(curves[s][dict(plan[s])[fixed_spec][0].label])

    def placebo_pair(s, label):
        if placebo is None or s == placebo or label not in curves[placebo]:
            return None
        (F0, d0), (O0, e0) = fixed_of(placebo), mse(curves[placebo][label])
        ok = ~(d0 | e0)
        return (F0[ok], O0[ok]) if ok.any() else None

    out = {"min_ci_episodes": MIN_CI_EPISODES, "fixed": fixed_spec, "placebo": placebo, "scenarios": {}}
    for s, per in curves.items():
        fixed_label = dict(plan[s])[fixed_spec][0].label
        F, dF = fixed_of(s)
        summ = results["scenarios"][s]
        oracle_labels = [lab for lab in per if is_oracle_label(lab)]
        knob = next((lab for lab in oracle_labels if _oracle_kind(lab) == "oracle-schedule"), None)
        note = (f"this is the placebo scenario (no events): an oracle's headroom here is luck" if s == placebo
                else f"placebo: {placebo}" if placebo else
                f"placebo not measured (add --scenario {PLACEBO_SCENARIO})")
        best = best_hand_designed(plan[s], summ)
        entry = {"note": note, "fixed": {"label": fixed_label, "rmse_h_m": summ[fixed_label]["rmse_h_m"],
                                         "episodes": int(F.size)},
                 "knob_oracle": knob, "best_hand_designed": best, "oracles": {}, "methods": {}}
        for lab in oracle_labels:
            O, dO = mse(per[lab])
            ok = ~(dF | dO)
            h = (headroom(F[ok], O[ok], placebo=placebo_pair(s, lab)) if ok.any() else
                 {"episodes": 0, "headroom": None, "ci_note": "no episode without a divergence"})
            entry["oracles"][lab] = {"kind": _oracle_kind(lab), "rmse_h_m": summ[lab]["rmse_h_m"], **h}
            if best is None:
                fb = {"episodes": 0, "headroom": None, "headroom_ci95": None,
                      "ci_note": "no hand-designed method with a finite RMSE"}
            else:
                B, dB = mse(per[best["label"]])
                ok = ~(dB | dO)
                fb = ({k: v for k, v in headroom(B[ok], O[ok]).items()
                       if k in ("episodes", "headroom", "headroom_ci95", "ci_note")} if ok.any() else
                      {"episodes": 0, "headroom": None, "headroom_ci95": None,
                       "ci_note": "no episode without a divergence"})
            entry["oracles"][lab]["from_best"] = fb
        for label, a, d, learned, pooled, rmse in _compared_mse_rows(results, per, plan[s], s, fixed_label):
            row = {"learned": learned, "pooled": pooled, "rmse_h_m": rmse}
            if knob is None:
                row.update(episodes=int(a.size), share=None, share_ci95=None, note="no knob oracle: add "
                           "'oracle-schedule:<env id>' to --methods")
            else:
                O, dO = mse(per[knob])
                ok = ~(dF | d | dO)
                if ok.any():
                    row.update(headroom_share(F[ok], a[ok], O[ok], placebo=placebo_pair(s, knob)))
                    if s == placebo:
                        row["note"] = "; ".join(filter(None, ["placebo scenario: share of the gross headroom",
                                                              row.get("note")]))
                else:
                    row.update(episodes=0, share=None, share_ci95=None, note="no episode without a divergence")
            entry["methods"][label] = row
        out["scenarios"][s] = entry
    return out


def compute_gap_to_oracle_r(results: dict, curves: dict, plan: dict) -> dict:
    """The ``"gap_to_oracle_r"`` section of results.json: per scenario with an ``oracle-r`` row (the R oracle,
    the floor of the per-satellite action space), the share of the gap from the reference to it that each other
    method closed, ``(R_ref - R_m) / (R_ref - R_oracle)`` (:func:`envs.metrics.headroom_share`, no placebo):
    1 reaches the oracle, 0 the reference, < 0 worse than the reference. With the scenario's best hand-designed
    method as ``--reference``, the share of the per-satellite headroom a method closed (docs/results-satellite.md).

    Schema (RMSEs in metres, shares as fractions, CIs ``[lo, hi]`` or null below ``min_ci_episodes``)::

        {"<scenario>": {"reference": "<label>", "oracle": "<oracle-r label>",
                        "methods": {"<label>": {"learned", "pooled", "rmse_h_m", "episodes", "share",
                                                "share_ci95", "gap_m", "gap_ci95_m", "note"}}}}

    Rows: every method that is neither an oracle nor the reference (each training seed and the pooled row of a
    seed group, as :func:`compute_headroom`). Episodes where the reference, the method or the oracle diverged
    leave that comparison. Scenarios without an ``oracle-r`` row are absent.
    """
    from envs.metrics import headroom_share
    mse = _episode_mse
    out = {}
    for s, per in curves.items():
        oracle = next((lab for lab in per if _oracle_kind(lab) == "oracle-r"), None)
        if oracle is None:
            continue
        ref = results["config"]["reference_labels"][s]
        (R, dR), (O, dO) = mse(per[ref]), mse(per[oracle])
        methods = {}
        for label, a, d, learned, pooled, rmse in _compared_mse_rows(results, per, plan[s], s, ref):
            ok = ~(dR | d | dO)
            row = {"learned": learned, "pooled": pooled, "rmse_h_m": rmse}
            row.update(headroom_share(R[ok], a[ok], O[ok]) if ok.any() else
                       {"episodes": 0, "share": None, "share_ci95": None, "note": "no episode without a divergence"})
            row.pop("net", None)
            methods[label] = row
        out[s] = {"reference": ref, "oracle": oracle, "methods": methods}
    return out


def format_gap_to_oracle_r(g: dict, labels: dict | None = None) -> str:
    """Markdown table of the ``"gap_to_oracle_r"`` section (:func:`compute_gap_to_oracle_r`); ``labels`` as in
    :func:`format_headroom`."""
    rows = ["| scenario | method | episodes | RMSE h [m] | gap reference - oracle-r [m] (95% CI) | "
            "share of the gap closed (95% CI) |", "|" + "---|" * 6]
    for s, e in g.items():
        lab = (labels or {}).get(s, {})
        for m_lab, m in e["methods"].items():
            gap = ("-" if m.get("gap_m") is None else f"{m['gap_m']:.2f}" + (
                "" if m.get("gap_ci95_m") is None else f" [{m['gap_ci95_m'][0]:.2f}, {m['gap_ci95_m'][1]:.2f}]"))
            kind = " (learned)" if m["learned"] else ""
            rows.append(f"| {s} | {lab.get(m_lab, m_lab)}{kind} | {m['episodes']} | {m['rmse_h_m']:.3f} | {gap} | "
                        f"{gap_share_text(m['share'], m['share_ci95'], m.get('note'))} |")
    return "\n".join(rows)


def best_hand_designed(plan_s: list, summ: dict) -> dict | None:
    """The best hand-designed method of one scenario, for :func:`compute_headroom`.

    Parameters
    ----------
    plan_s : ``[(spec, [methods])]`` of the scenario (eval.py's plan).
    summ : ``{label: metrics}`` of the scenario in results.json (:func:`envs.metrics.summarize`).

    Returns
    -------
    ``{"label", "rmse_h_m", "episodes", "diverged", "candidates"}`` of the candidate row with the lowest
    ``rmse_h_m`` (the first of equals, in ``--methods`` order), or None when no candidate has a finite RMSE.
    The candidates are the method rows that are neither oracles (:func:`agents.methods.is_oracle_label`) nor
    learned policies (:class:`agents.methods.PolicyMethod`); each member of a seed group counts as a row (the
    group's pooled row is their average, not a method of its own). ``rmse_h_m`` leaves diverged episodes out,
    as the results table does; ``diverged`` says how many there were.
    """
    from agents.methods import PolicyMethod, is_oracle_label
    cands = [m.label for _, ms in plan_s for m in ms if not (is_oracle_label(m.label) or getattr(m, "is_oracle", False)
                                                             or isinstance(m, PolicyMethod))]
    best = None
    for lab in cands:
        r = summ[lab]["rmse_h_m"]
        if r is not None and np.isfinite(r) and (best is None or r < summ[best]["rmse_h_m"]):
            best = lab
    if best is None:
        return None
    return {"label": best, "rmse_h_m": summ[best]["rmse_h_m"], "episodes": summ[best]["episodes"],
            "diverged": summ[best]["diverged"], "candidates": cands}


def _pct(x, signed=True):
    return "n/a" if x is None else (f"{100 * x:+.1f}%" if signed else f"{100 * x:.1f}%")


def _pct_ci(v, ci, note):
    if v is None:
        return note or "n/a"
    return f"{_pct(v)} [{_pct(ci[0])}, {_pct(ci[1])}]" if ci is not None else f"{_pct(v)} ({note or 'no CI'})"


def format_headroom(h: dict, labels: dict | None = None) -> str:
    """Markdown table of the ``"headroom"`` section (:func:`compute_headroom`) and its notes per scenario;
    ``labels`` (``{scenario: {row label: short label}}``, :func:`method_labels`) names the rows (default: the
    labels themselves)."""
    head = ("| scenario | row | episodes | RMSE h [m] | headroom (95% CI) | net of placebo (95% CI) | "
            "share of the knob headroom closed (95% CI) | headroom from the best hand-designed (95% CI) |")
    rows = [head, "|" + "---|" * 8]
    notes = []
    for s, e in h["scenarios"].items():
        lab = (labels or {}).get(s, {})
        f = e["fixed"]
        rows.append(f"| {s} | optimized fixed: {lab.get(f['label'], f['label'])} | {f['episodes']} | "
                    f"{f['rmse_h_m']:.3f} | - | - | - | - |")
        for o_lab, o in e["oracles"].items():
            net = ("placebo" if s == h["placebo"] else "not measured" if o.get("net_headroom") is None
                   else _pct_ci(o["net_headroom"], o["net_headroom_ci95"], o["ci_note"]))
            knob = " (knob)" if o_lab == e["knob_oracle"] else ""
            fb = o.get("from_best")
            from_best = "-" if fb is None else _pct_ci(fb["headroom"], fb["headroom_ci95"], fb["ci_note"])
            rows.append(f"| {s} | {lab.get(o_lab, o_lab)}{knob} | {o['episodes']} | {o['rmse_h_m']:.3f} | "
                        f"{_pct_ci(o['headroom'], o.get('headroom_ci95'), o['ci_note'])} | {net} | - | {from_best} |")
        for m_lab, m in e["methods"].items():
            share = _pct_ci(m["share"], m["share_ci95"], m.get("note"))
            if m["share"] is not None and m.get("note") and m["share_ci95"] is not None:
                share += f" ({m['note']})"
            kind = " (learned)" if m["learned"] else ""
            rows.append(f"| {s} | {lab.get(m_lab, m_lab)}{kind} | {m['episodes']} | {m['rmse_h_m']:.3f} | - | - | "
                        f"{share} | - |")
        notes.append(f"- `{s}`: {e['note']}" + ("" if e["knob_oracle"] else
                                                 "; no knob oracle ('oracle-schedule:<env id>') in --methods"))
        if "best_hand_designed" in e:
            notes.append(f"- `{s}`: {_best_note(e['best_hand_designed'], lab)}")
    return "\n".join(rows + [""] + notes)


def _best_note(b: dict | None, labels: dict | None = None) -> str:
    """The note's sentence naming a scenario's best hand-designed method (:func:`best_hand_designed`), by its
    short label where ``labels`` has one."""
    if b is None:
        return "best hand-designed method: none (no hand-designed row with a finite RMSE)"
    div = (f"; diverged in {b['diverged']} of {b['episodes']} episodes, left out of its RMSE as in the results "
           "table" if b["diverged"] else "")
    name = (labels or {}).get(b["label"], b["label"])
    return (f"best hand-designed method: {name} (RMSE h {b['rmse_h_m']:.3f} m, the lowest of "
            f"{len(b['candidates'])} hand-designed row{'s' if len(b['candidates']) != 1 else ''}{div}); the "
            "oracles' headroom from it is the last column")


def _ref_label(results: dict, s: str) -> str:
    c = results["config"]
    return c.get("reference_labels", {}).get(s, c["reference"])


def _trained_on(results: dict) -> list[str]:
    """The note's section on what each tuned or learned method was trained on (:mod:`agents.provenance`)."""
    from agents.provenance import training_notes
    groups = {s: {spec: g["members"] for spec, g in per.items()} for s, per in results.get("seed_groups", {}).items()}
    items = training_notes({s: list(per) for s, per in results["scenarios"].items()},
                           results["config"].get("episode_length_s"), groups)
    return ["## What the tuned and learned methods were trained on", "", *items, ""] if items else []


def _skipped(results: dict) -> list[str]:
    """The note's list of methods left out of a scenario by ``--skip-missing`` (no file there)."""
    items = [f"- `{k['scenario']}`: `{k['method']}` ({k['why']})" for k in results["config"].get("skipped", [])]
    return ["## Methods not run on every scenario", "",
            "Left out where their file pattern matches nothing (`--skip-missing`): not trained there.", "",
            *items, ""] if items else []


def _label_key(results: dict) -> list[str]:
    """The note's key from the short labels of the tables to the full method specs (results.json's keys):
    one item per spec whose short label differs from it, its label per scenario where they differ."""
    seen: dict = {}  # spec -> {short label: [scenarios]}
    for s in results["scenarios"]:
        for m, short in method_labels(results, s).items():
            if short != m:
                seen.setdefault(m, {}).setdefault(short, []).append(s)
    items = []
    for m, shorts in seen.items():
        if len(shorts) == 1:
            items.append(f"- {next(iter(shorts))}: `{m}`")
        else:
            items.append(f"- `{m}`: " + ", ".join(f"{sh} (" + ", ".join(f"`{x}`" for x in sc) + ")"
                                                  for sh, sc in shorts.items()))
    return ["Methods by their short labels:", "", *items, ""] if items else []


def write_note(results: dict, path: Path, out: Path, cmd: str) -> None:
    """A Markdown results note generated from results.json (never typed by hand): it opens with one verdict
    per scenario (:func:`verdict_sentence`), then the command, the table (short labels, keyed to the full
    specs), the reading, what the tuned and learned methods were trained on and the headroom."""
    path.parent.mkdir(parents=True, exist_ok=True)
    c = results["config"]
    from agents.methods import is_oracle_label
    groups = any(results.get("seed_groups", {}).values())
    oracles = any(is_oracle_label(m) for per in results["scenarios"].values() for m in per)
    all_labels = {s: method_labels(results, s) for s in results["scenarios"]}
    lines = ["# navgym results", "", *(f"- {verdict_sentence(results, s)}" for s in results["scenarios"]), "",
             f"Generated by `python eval.py {cmd}` ({time.strftime('%Y-%m-%d')}); "
             f"{c['episodes']} paired episodes per scenario, seed {c['seed']}, filter arithmetic {c['dtype']}. "
             f"Differences are method minus the reference (`{c['reference']}`), paired over the episodes, "
             "with bootstrap 95% CIs"
             + ("; a method given as a pattern over training seeds has a row per seed and a pooled row (the CI "
                "resamples episodes, each with all its seeds)" if groups else "")
             + ("; oracle rows know the truth: they bound what a method could reach, no user could run them"
                if oracles else "") + ".", "",
             format_table(results), "", *_label_key(results),
             "## Reading", "", *reading(results, results["config"].get("goal")), "",
             *_trained_on(results), *_skipped(results),
             *(["## Share of the gap to oracle-r", "", GAP_INTRO, "",
                format_gap_to_oracle_r(results["gap_to_oracle_r"], all_labels), ""]
               if "gap_to_oracle_r" in results else []),
             *(["## Headroom", "", HEADROOM_INTRO, "", format_headroom(results["headroom"], all_labels), ""]
               if "headroom" in results else []),
             f"Plots and raw numbers: `{out}` (results.json, results.csv, *.png).", ""]
    from envs.outputs import write_atomic
    write_atomic(path, "\n".join(lines))


if __name__ == "__main__":
    main()
