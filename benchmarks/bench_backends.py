"""The same eval.py evaluation on ``--backend local`` and ``--backend ray`` side by side, and what travels.

Runs ``eval.py`` twice as subprocesses (wall time of the whole command, Ray's start included), checks that
the two results.json agree with the timing fields left out, and measures one batch: the bytes of its task
(what is sent: the method and the seeds), of its result (what comes back: the method's episode log of the
batch, pickled as Ray pickles it) and of the world it generates where it runs (what never travels).

    python benchmarks/bench_backends.py                          # 50 episodes x 6 methods x 3 scenarios
    python benchmarks/bench_backends.py --episodes 8 --workers 2 # smaller
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from envs.json_io import without_timing  # noqa: E402

METHODS = "kf,sage-husa,stkf,ma-stkf,svd-akf,rule:GnssIns/SageHusa-v1"
SCENARIOS = ("noise-burst", "urban", "open-sky")


def nbytes(obj, seen=None) -> int:
    """Bytes of the numpy arrays reachable from ``obj`` (dataclasses, dicts, lists, attributes)."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return sum(nbytes(getattr(obj, f.name), seen) for f in dataclasses.fields(obj))
    if isinstance(obj, dict):
        return sum(nbytes(v, seen) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(nbytes(v, seen) for v in obj)
    if hasattr(obj, "__dict__") and not isinstance(obj, type):
        return sum(nbytes(v, seen) for v in vars(obj).values())
    return 0


def run_eval(backend: list[str], args, out: Path) -> float:
    cmd = [sys.executable, str(ROOT / "eval.py"), *[a for s in args.scenario for a in ("--scenario", s)],
           "--methods", args.methods, "--episodes", str(args.episodes), "--seed", "0", "--no-plots",
           "--batch-size", str(args.batch_size), "--out", str(out), *backend]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"eval.py {' '.join(backend)} failed:\n{p.stderr[-3000:]}")
    return wall


def batch_bytes(args) -> dict:
    """Bytes of one batch's task, result and world (first scenario, first chunk, each method)."""
    from agents.eval_batches import plan_batches, run_eval_batch, world_for
    from agents.methods import expand_method_spec
    import eval as eval_cli
    scen = args.scenario[0]
    seeds = eval_cli.episode_seeds(0, args.episodes)[:args.batch_size]
    methods = [m for spec in eval_cli._split_methods(args.methods) for m in expand_method_spec(spec, scen)]
    out = {"scenario": scen, "episodes_per_batch": len(seeds), "methods": {}}
    for b in plan_batches({scen: methods}, seeds, args.batch_size):
        res = run_eval_batch(b)
        out["methods"][b.method.label] = {
            "task_bytes": len(pickle.dumps(b, protocol=5)),
            "result_bytes": len(pickle.dumps(dataclasses.replace(res, track=None), protocol=5)),
            "epochs": int(res.log.t.size)}
    out["world_bytes"] = nbytes(world_for(scen, seeds))
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--scenario", action="append", default=None, help=f"default: {', '.join(SCENARIOS)}")
    p.add_argument("--methods", default=METHODS)
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    args.scenario = args.scenario or list(SCENARIOS)
    n_methods = len(args.methods.split(","))
    print(f"evaluation: {args.episodes} episodes x {n_methods} methods x {len(args.scenario)} scenarios "
          f"({', '.join(args.scenario)}), batch size {args.batch_size}; {os.cpu_count()} CPU cores here")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t_local = run_eval([], args, tmp / "local")
        t_ray = run_eval(["--backend", "ray", "--workers", str(args.workers)], args, tmp / "ray")
        a = json.loads((tmp / "local" / "results.json").read_text())
        b = json.loads((tmp / "ray" / "results.json").read_text())
    same = without_timing(a) == without_timing(b)
    print("\n| backend | wall time [s] | speed-up |\n|---|---|---|")
    print(f"| local (this process) | {t_local:.1f} | 1.00 |")
    print(f"| ray, {args.workers} workers (local Ray started by eval.py) | {t_ray:.1f} | {t_local / t_ray:.2f} |")
    print(f"\nresults.json identical without timing fields: {same}")
    bb = batch_bytes(args)
    print(f"\none batch = one method on {bb['episodes_per_batch']} episodes of {bb['scenario']}:")
    print("| method | epochs | task sent [B] | result back [B] | back per episode [B] |\n|---|---|---|---|---|")
    for label, m in bb["methods"].items():
        print(f"| {label} | {m['epochs']} | {m['task_bytes']} | {m['result_bytes']} | "
              f"{m['result_bytes'] / bb['episodes_per_batch']:.0f} |")
    print(f"the world it generates where it runs (never sent): {bb['world_bytes']} B "
          f"({bb['world_bytes'] / 2**20:.1f} MiB)")
    back = np.mean([m["result_bytes"] for m in bb["methods"].values()])
    print(f"mean result per batch {back / 2**20:.2f} MiB: {8 * back / 1e9:.3f} s on a 1 Gbit/s link")
    if not same:
        raise SystemExit("the backends disagree")


if __name__ == "__main__":
    main()
