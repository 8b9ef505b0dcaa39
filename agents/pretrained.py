"""Shipping trained models: pick one run of several by its own held-out figure and copy its files.

The choice never looks at the episodes a results note evaluates on:

| what | candidates | picked by | files copied |
|---|---|---|---|
| policy | ``train.py rl`` run folders (``config.json`` with ``"status": "complete"``) | the highest ``eval_mean_reward_last`` (the training run's last evaluation, on its own evaluation seeds, 900000 + k) | ``model.zip``, ``vecnormalize.pkl`` (when the run has one), ``config.json`` |
| learned-r | ``train.py learned-r`` output folders | the lowest validation NLL (``metrics.json``: ``val.nll_m``) | ``model.pt``, ``config.json``, ``metrics.json`` |

The copied ``config.json`` gains a ``"pretrained"`` key: the source folder, the criterion and every candidate's
figure. Usage::

    python -m agents.pretrained --out pretrained --policies 'runs/satellite-r/urban-smartloc/ppo-s*' \\
        --learned-r 'runs/learned-r/urban-smartloc-*'

writes ``pretrained/satellite-r/`` and ``pretrained/learned-r/`` (each file atomically).
"""
from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

POLICY_FILES = ("model.zip", "vecnormalize.pkl", "config.json")
LEARNED_R_FILES = ("model.pt", "config.json", "metrics.json")


def _read_json(path: Path) -> dict:
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: unreadable JSON ({e})") from None
    if not isinstance(d, dict):
        raise ValueError(f"{path}: not a JSON object")
    return d


def _folders(patterns) -> list[Path]:
    runs = sorted({Path(p) for pat in patterns for p in glob.glob(pat) if Path(p).is_dir()})
    if not runs:
        raise ValueError(f"no run folder matches {' '.join(patterns)}")
    return runs


def pick_policy(patterns) -> tuple[Path, dict]:
    """The complete ``train.py rl`` run with the highest ``eval_mean_reward_last`` among the folders matching
    ``patterns`` (glob strings); returns ``(folder, {folder: figure})``. ``ValueError`` when none matches or
    none is complete with a finite figure."""
    figures = {}
    for run in _folders(patterns):
        cfg = run / "config.json"
        if not cfg.is_file() or not (run / "model.zip").is_file():
            continue
        c = _read_json(cfg)
        r = c.get("eval_mean_reward_last")
        if c.get("status") == "complete" and isinstance(r, (int, float)) and r == r and abs(r) != float("inf"):
            figures[str(run)] = float(r)
    if not figures:
        raise ValueError(f"no complete run with an evaluation reward among {' '.join(patterns)}")
    best = max(figures, key=figures.get)
    return Path(best), figures


def pick_learned_r(patterns) -> tuple[Path, dict]:
    """The ``train.py learned-r`` folder with the lowest validation NLL (``metrics.json``: ``val.nll_m``)
    among the folders matching ``patterns``; returns ``(folder, {folder: NLL})``."""
    figures = {}
    for run in _folders(patterns):
        m = run / "metrics.json"
        if m.is_file() and (run / "model.pt").is_file():
            v = _read_json(m).get("val", {}).get("nll_m")
            if isinstance(v, (int, float)) and v == v:
                figures[str(run)] = float(v)
    if not figures:
        raise ValueError(f"no learned-r folder with a validation NLL among {' '.join(patterns)}")
    best = min(figures, key=figures.get)
    return Path(best), figures


def ship(src: Path, dst: Path, files, criterion: str, figures: dict) -> list[Path]:
    """Copy ``files`` of ``src`` into ``dst`` (each atomically; a missing optional ``vecnormalize.pkl`` is
    skipped), adding ``{"pretrained": {"source", "criterion", "candidates"}}`` to the copied ``config.json``.
    Returns the written paths."""
    from envs.outputs import write_atomic
    dst.mkdir(parents=True, exist_ok=True)
    written = []
    for name in files:
        f = src / name
        if not f.is_file():
            if name == "vecnormalize.pkl":
                continue
            raise ValueError(f"{f}: missing")
        if name == "config.json":
            c = _read_json(f)
            c["pretrained"] = {"source": str(src), "criterion": criterion, "candidates": figures}
            write_atomic(dst / name, json.dumps(c, indent=2) + "\n")
        else:
            write_atomic(dst / name, f.read_bytes())
        written.append(dst / name)
    return written


def main(argv=None) -> list[Path]:
    p = argparse.ArgumentParser(prog="python -m agents.pretrained", description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="folder that receives satellite-r/ and learned-r/")
    p.add_argument("--policies", nargs="+", default=None, metavar="GLOB",
                   help="train.py rl run folders to pick the shipped policy from (-> OUT/satellite-r/)")
    p.add_argument("--learned-r", nargs="+", default=None, metavar="GLOB",
                   help="train.py learned-r folders to pick the shipped model from (-> OUT/learned-r/)")
    args = p.parse_args(argv)
    out, written = Path(args.out), []
    try:
        if args.policies:
            run, figs = pick_policy(args.policies)
            written += ship(run, out / "satellite-r", POLICY_FILES, "max eval_mean_reward_last", figs)
        if args.learned_r:
            run, figs = pick_learned_r(args.learned_r)
            written += ship(run, out / "learned-r", LEARNED_R_FILES, "min val.nll_m", figs)
    except ValueError as e:
        p.exit(2, f"agents.pretrained: {e}\n")
    print("wrote " + ", ".join(map(str, written)))
    return written


if __name__ == "__main__":
    main()
