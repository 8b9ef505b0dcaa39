"""The experiments' entry point: :func:`run_experiment` runs one and writes its results and report."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from envs.json_io import jsonable
from .claims import verdict_summary
from .navigation import episode_seeds
from .seed000 import run_seed000
from .seed001 import run_seed001
from .seed003 import run_seed003

EXPERIMENTS = ("seed000", "seed001", "seed003")
"""Experiment names accepted by :func:`run_experiment`."""


DEFAULT_EPISODES = {"seed000": 50, "seed001": 20, "seed003": 20}
"""Episodes per experiment when ``episodes`` is None (seed 000 ran 50 Monte Carlo runs, sec 5.1.1)."""


_RUNNERS = {"seed000": run_seed000, "seed001": run_seed001, "seed003": run_seed003}


def run_experiment(name: str, episodes: int | None = None, seed: int = 0, out_dir=None, progress=None,
                   batch_size: int | None = None, duration_s: float | None = None) -> tuple[dict, str]:
    """Run one reproduction experiment.

    Parameters
    ----------
    name : one of :data:`EXPERIMENTS`.
    episodes : paired Monte Carlo episodes (default :data:`DEFAULT_EPISODES`).
    seed : base seed (episode k: ``seed * 1_000_003 + k``).
    out_dir : if given, write ``<out_dir>/<name>.json`` and ``<out_dir>/<name>.md``.
    progress : optional callable ``progress(message: str)`` called before each run.
    batch_size : episodes per batched navigator (default: all episodes in one batch, at most 50; 25 for the
        700 s seed003 worlds).
    duration_s : if given, every scenario of the experiment is cut to this length [s] (smoke runs; the
        paper comparisons need the full scenarios).

    Returns
    -------
    results : dict (module docstring); report : Markdown text with 'paper' and 'ours' figures side by side.
    """
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; known: {list(EXPERIMENTS)}")
    if episodes is None:
        episodes = DEFAULT_EPISODES[name]
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"episodes must be a positive int, got {episodes!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    if batch_size is None:
        batch_size = 25 if name == "seed003" else 50
    if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive int, got {batch_size!r}")
    if duration_s is not None and (isinstance(duration_s, bool) or not isinstance(duration_s, (int, float))
                                   or not math.isfinite(duration_s) or duration_s <= 0):
        raise ValueError(f"duration_s must be a positive number of seconds or None, got {duration_s!r}")
    seeds = episode_seeds(int(seed), int(episodes))
    t0 = time.perf_counter()
    body, report = _RUNNERS[name](seeds, batch_size=int(batch_size), progress=progress, duration_s=duration_s)
    wall = time.perf_counter() - t0
    results = {"experiment": name, "episodes": int(episodes), "seed": int(seed), "episode_seeds": seeds,
               "wall_time_s": wall, "duration_s": None if duration_s is None else float(duration_s), **body}
    cut = "" if duration_s is None else f"**Smoke run: every scenario cut to {duration_s:g} s; not a comparison.**\n\n"
    report = (f"# Reproduction `{name}`: paper figures beside ours\n\n{cut}{report}\n\n"
              f"{verdict_summary(body['claims'])} {episodes} episodes, seed {seed}, wall time {wall:.1f} s.\n")
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        from envs.outputs import write_atomic
        write_atomic(out / f"{name}.json", json.dumps(jsonable(results), indent=2))
        write_atomic(out / f"{name}.md", report)
    return results, report
