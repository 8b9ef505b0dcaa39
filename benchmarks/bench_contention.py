"""Env throughput with a core busy: the same cells idle and beside one competing CPU-bound process.

The native vector env's row kernels run parallel from 64 rows on; a parallel launch waits for its slowest thread,
so a core that another process keeps busy slows every launch down (measured on 2 cores: sage-husa at B = 1024 fell
from 43k to 8.5k env-steps/s). The env's ``parallel_kernels`` picks the row kernels' mode: ``always`` (parallel),
``never`` (serial) or ``auto`` (both measured, the faster run: :class:`nav_filters.parallel_governor.
ParallelGovernor`). This benchmark runs each cell twice, *idle* and *busy* (with ``--competitors`` processes
running ``while True: pass`` at normal priority, started before the cell and killed after it, also on Ctrl-C or an
error), each in a fresh process, and prints a Markdown table with the busy figure's ratio to the cell's own idle
figure (the target: no cell below 0.5) and to the idle figure of ``always`` (the fixed rule) of the same layer
and kind.

Cells (``--methods``, default sage-husa, in the env default fused mode, at ``--batch`` rows, default 1024):

* ``end to end``: env-steps/s as a training loop pays it, automatic resets included (``bench_envs.
  bench_end_to_end``: ``2 M + 5`` zero-action steps for M epochs per episode after an untimed first episode, at
  B >= 20 (more episodes below, ``bench_envs.e2e_episodes``); two automatic resets inside, each drawing its rows'
  new worlds; the governor's probes inside, its start in the untimed episode);
* ``step-only``: 30 steps (``--steps``) inside one episode after 12 untimed ones (``bench_envs.bench_env``;
  ``auto`` has made its first decision by then, and 30 steps hold its probes in their share).

Threading layers and OpenMP's wait policy (numba picks its layer once per process; tbb is not a dependency):
the cells of ``--policies`` run under numba's default layer (whatever the environment says: ``omp`` where libgomp
is found); the cells of ``--layer-policies`` (default ``always``, the mode the layer matters for) also under
each of ``--layers``: ``omp-passive`` (``NUMBA_THREADING_LAYER=omp OMP_WAIT_POLICY=passive``: idle OpenMP threads
sleep at once instead of spinning), ``omp`` and ``workqueue`` (``NUMBA_THREADING_LAYER=workqueue``, numba's own
pool). The layer a cell ran on is printed (``-`` where it launched no parallel kernel).

Usage::

    python benchmarks/bench_contention.py [--quick] [--methods sage-husa] [--batch 1024] [--rounds 1]
                                          [--policies always never auto] [--kinds e2e step]
                                          [--layers omp-passive workqueue] [--layer-policies always]

The default run is 10 cells (3 policies x 2 kinds under the default layer, 2 layers x ``always`` x 2 kinds), each
idle and busy: 20 fresh processes, about 5 to 8 minutes on 2 cores (an end-to-end run at B = 1024 takes ~10-40 s,
the busy parallel ones the longest). ``--quick``: B = 128, 20 s episodes, 3 timed step-only steps (a smoke test
of the whole run, 1-3 minutes: most of it the processes' start-up).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from contextlib import contextmanager

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

POLICIES = ("always", "never", "auto")
KINDS = {"e2e": "end to end", "step": "step-only"}
LAYERS = {
    "default": {},
    "omp": {"NUMBA_THREADING_LAYER": "omp"},
    "omp-passive": {"NUMBA_THREADING_LAYER": "omp", "OMP_WAIT_POLICY": "passive"},
    "workqueue": {"NUMBA_THREADING_LAYER": "workqueue"},
}
"""Layer configurations: the environment variables a cell's process gets on top of this process's (``default``:
none; numba's own choice)."""

SPIN = ("import os\n"
        "parent = os.getppid()\n"
        "while os.getppid() == parent:  # (ends by itself if the benchmark dies without killing it)\n"
        "    for _ in range(100000):\n"
        "        pass\n")
"""The competing process: pure-Python busy work on one core, at normal priority."""


@contextmanager
def competing_load(n: int = 1):
    """Context manager: ``n`` CPU-bound processes (:data:`SPIN`) run while the body runs; they are killed and
    reaped on exit, also when the body raises (Ctrl-C included). Yields the ``subprocess.Popen`` objects."""
    procs = []
    try:
        for _ in range(n):
            procs.append(subprocess.Popen([sys.executable, "-c", SPIN], stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        yield procs
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        for p in procs:
            p.wait(timeout=30)


def run_cell(cell: dict, layer: str = "default", root: str = ROOT) -> dict:
    """One cell in a fresh process with the environment of ``LAYERS[layer]``; returns its JSON result
    (:func:`cell_main`), or ``{"error": message}`` where the process failed."""
    env = dict(os.environ, **LAYERS[layer])
    cmd = [sys.executable, os.path.abspath(__file__), "--cell", json.dumps(cell)]
    res = subprocess.run(cmd, env=env, cwd=root, capture_output=True, text=True)
    if res.returncode != 0:
        tail = (res.stderr.strip().splitlines() or ["exit status %d" % res.returncode])[-1]
        return {"error": tail}
    return json.loads(res.stdout.strip().splitlines()[-1])


def cell_main(cell: dict) -> dict:
    """Run one cell in this process: ``{"rate": env-steps/s, "cpu_ms": CPU ms per batched step, "layer": numba's
    threading layer or '-', "governor": the env's governor summary}`` (``cell``: method, B, kind, policy,
    episode_s, scenario, steps)."""
    sys.path.insert(0, HERE)
    import bench_envs

    seen = {}
    kw = dict(env_kwargs={"parallel_kernels": cell["policy"]}, before_close=lambda env: seen.update(
        governor=env.unwrapped.parallel_governor.summary()))
    if cell["kind"] == "e2e":
        rate, _, cpu, _ = bench_envs.bench_end_to_end(cell["method"], cell["B"], cell["episode_s"], cell["scenario"],
                                                   "fused", **kw)
    else:
        _, rate, cpu = bench_envs.bench_env(cell["method"], cell["B"], cell["steps"], cell["episode_s"],
                                            cell["scenario"], "fused", **kw)
    import numba
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel ran in this process
        layer = "-"
    return {"rate": rate, "cpu_ms": cpu, "layer": layer, "governor": seen.get("governor")}


def _grid(args) -> list:
    """The (layer, policy, kind, method) cells of a run, in the order they run."""
    cells = [("default", p, k, m) for m in args.methods for k in args.kinds for p in args.policies]
    cells += [(lay, p, k, m) for lay in args.layers for m in args.methods for k in args.kinds
              for p in args.layer_policies]
    return cells


def measure(args, run=run_cell, load=competing_load, log=sys.stderr) -> dict:
    """Every cell of :func:`_grid` idle and busy, ``args.rounds`` times (each round runs every cell, idle then busy,
    before the next round). Returns ``{(layer, policy, kind, method): {"idle": [results], "busy": [results]}}``."""
    out = {c: {"idle": [], "busy": []} for c in _grid(args)}
    for r in range(args.rounds):
        for c in out:
            layer, policy, kind, method = c
            spec = dict(method=method, B=args.batch, kind=kind, policy=policy, episode_s=args.episode_s,
                        scenario=args.scenario, steps=args.steps)
            out[c]["idle"].append(run(spec, layer))
            with load(args.competitors):
                out[c]["busy"].append(run(spec, layer))
            print(f"round {r + 1}/{args.rounds}: {layer} {policy} {kind} {method} done", file=log, flush=True)
    return out


def _median(results):
    import numpy as np
    rates = [x["rate"] for x in results if "error" not in x]
    return float(np.median(rates)) if rates else None


def _governor_note(results) -> str:
    g = next((x.get("governor") for x in reversed(results) if x.get("governor")), None)
    if not g or not g["active"]:
        return "-" if not g else f"{g['policy']} (fixed)"
    return f"{g['preferred']} (switches: {g['switches']}, probes: {g['probes']})"


def table(args, out) -> list:
    """The Markdown table of :func:`measure`'s results (lines) and the verdict line."""
    lines = [f"| layer | policy | kind | method | B | idle env-steps/s | busy env-steps/s | busy / idle | "
             f"busy / idle of always | auto: mode when busy |",
             "|---|---|---|---|---:|---:|---:|---:|---:|---|"]
    below = []
    for (layer, policy, kind, method), res in out.items():
        idle, busy = _median(res["idle"]), _median(res["busy"])
        ran = sorted({x["layer"] for x in res["idle"] + res["busy"] if "layer" in x} - {"-"})
        name = layer + (f" ({'/'.join(ran)})" if ran and ran != [layer] else "")  # the configuration (the layer)
        ref = out.get((layer, "always", kind, method)) or out.get(("default", "always", kind, method)) or res
        ref_idle = _median(ref["idle"])
        errs = [x["error"] for x in res["idle"] + res["busy"] if "error" in x]
        fmt = lambda v: "failed" if v is None else f"{v:,.0f}"  # noqa: E731
        ratio = busy / idle if idle and busy else None
        ratio_ref = busy / ref_idle if ref_idle and busy else None
        lines.append(f"| {name} | {policy} | {KINDS[kind]} | {method} | {args.batch} | {fmt(idle)} | {fmt(busy)} | "
                     + (f"{ratio:.2f}" if ratio else "-") + " | " + (f"{ratio_ref:.2f}" if ratio_ref else "-")
                     + f" | {_governor_note(res['busy']) if policy == 'auto' else '-'} |")
        if ratio is not None and ratio < 0.5:
            below.append(f"{name} {policy} {KINDS[kind]} {method}")
        for e in errs[:1]:
            lines.append(f"|  | (error: {e}) | | | | | | | | |")
    n = len(out)
    verdict = (f"target (busy >= 0.5 x idle in every cell): {n - len(below)} of {n} cells meet it"
               + (f"; below: {', '.join(below)}" if below else ""))
    return lines + ["", verdict]


def parse_args(argv=None):
    """The command line (module docstring), with the ``--quick`` defaults filled in."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="B = 128, 20 s episodes, 3 step-only steps (a smoke test)")
    sys.path.insert(0, HERE)
    from bench_envs import METHOD_ENV
    p.add_argument("--methods", nargs="+", default=["sage-husa"], choices=list(METHOD_ENV))
    p.add_argument("--batch", type=int, default=None, help="rows of the vector env (default 1024; --quick 128)")
    p.add_argument("--episode-s", type=float, default=None, help="episode length [s] (default 60; --quick 20)")
    p.add_argument("--steps", type=int, default=None, help="timed step-only steps (default 30; --quick 3)")
    p.add_argument("--scenario", default="noise-burst")
    p.add_argument("--policies", nargs="+", default=list(POLICIES), choices=POLICIES,
                   help="parallel_kernels of the cells under numba's default layer")
    p.add_argument("--kinds", nargs="+", default=list(KINDS), choices=list(KINDS),
                   help="e2e (resets included) and/or step (step-only)")
    p.add_argument("--layers", nargs="*", default=["omp-passive", "workqueue"],
                   choices=[k for k in LAYERS if k != "default"],
                   help="threading-layer configurations also run (none: skip the layer comparison)")
    p.add_argument("--layer-policies", nargs="+", default=["always"], choices=POLICIES,
                   help="parallel_kernels of the cells of --layers")
    p.add_argument("--competitors", type=int, default=1, help="competing CPU-bound processes of the busy cells")
    p.add_argument("--rounds", type=int, default=1, help="runs of every cell (the table shows the medians)")
    args = p.parse_args(argv)
    if args.rounds < 1:
        p.error(f"--rounds must be at least 1, got {args.rounds}")
    if args.competitors < 1:
        p.error(f"--competitors must be at least 1, got {args.competitors}")
    args.batch = args.batch or (128 if args.quick else 1024)
    args.episode_s = args.episode_s or (20.0 if args.quick else 60.0)
    args.steps = args.steps or (3 if args.quick else 30)
    if args.batch < 64:
        p.error(f"--batch must be at least 64 (PARALLEL_MIN_BATCH: below it every mode is serial), got {args.batch}")
    if 12 + args.steps >= args.episode_s and "step" in args.kinds:
        p.error(f"--steps {args.steps}: 12 untimed + {args.steps} timed steps must fit in one {args.episode_s:g} s "
                "episode")
    return args


def main(argv=None):
    args = parse_args(argv)
    t0 = time.perf_counter()
    print(f"navgym env throughput idle and beside {args.competitors} competing CPU-bound process(es): "
          f"{os.cpu_count()} CPUs, NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'unset')}, scenario "
          f"{args.scenario}, {args.episode_s:g} s episodes, fused mode; each cell in a fresh process"
          + (f", the median of {args.rounds} rounds" if args.rounds > 1 else "") + "\n", flush=True)
    out = measure(args)
    print("\n".join(table(args, out)))
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--cell":
        sys.path.insert(0, ROOT)
        print(json.dumps(cell_main(json.loads(sys.argv[2]))))
    else:
        main()
