"""The optimized fixed-parameter baseline: one constant parameter, tuned on training seeds, frozen.

A learned tuning policy is only credible against the best *constant* setting of the same parameter,
chosen on training episodes and evaluated on held-out ones (an optimized fixed filter erases most
apparent learned gains). :func:`tune_fixed_parameter` evaluates a grid of values on the training seeds in
one batched navigator (each grid value is a block of rows with the same worlds: the parameters are per
row) and writes the result file that ``eval.py`` reads as ``tuned:<path>``.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from envs.episodes import run_episodes
from envs.json_io import dumps

from .rollout import env_class

TRAIN_SEED_OFFSET = 500_000
"""Training seeds of the tuner start here: disjoint from eval.py's episode seeds (``seed * 1_000_003 + k``
for k < 500000)."""


def default_grid(spec, n: int = 13) -> np.ndarray:
    """``n`` values spanning the parameter's range, uniform in the parameter's action map."""
    return np.array([spec.to_value(a) for a in np.linspace(-1.0, 1.0, n)])


def tune_fixed_parameter(env_id: str, env_kwargs: dict | None = None, param: str | None = None, grid=None,
                         n_train: int = 16, seed: int = 0, progress=False) -> dict:
    """Grid search of one constant filter parameter on training seeds.

    Parameters
    ----------
    env_id : registered env id (its method, parameter ranges and defaults).
    env_kwargs : EnvConfig fields (scenario, episode_length_s, method, ...).
    param : the parameter to tune (default: the env's first); the others stay at their defaults.
    grid : values to try (default :func:`default_grid`).
    n_train : training episodes per grid value; seeds ``TRAIN_SEED_OFFSET + 1000 * seed + k``.
    progress : False (silent), True (a line per grid value on stderr, :func:`progress_line`, and the result
        on stdout) or a callable ``progress(line)`` taking all those lines.

    Returns
    -------
    dict with the env, method, parameter, grid, per-value horizontal RMSE [m] (diverged episodes count
    with the divergence bound), the best value and the training seeds.

    The training worlds are drawn once and every grid value runs on them, one value after another (a value's
    episodes in one batched navigator): the rows are independent, so the numbers are those of one batch of
    all values, and a line per value tells how far the search is.
    """
    env_kwargs = dict(env_kwargs or {})
    cls = env_class(env_id)
    cfg = cls.config_from(env_kwargs)
    if not cls.PARAMS:
        raise ValueError(f"{env_id} acts per receiver channel: it has no scalar parameter to tune")
    from envs.core import check_method_has_params
    check_method_has_params(cfg.method, cls.PARAMS, cls.DEFAULTS["method"])
    specs = {s.name: s for s in cls.PARAMS}
    param = param or cls.PARAMS[0].name
    if param not in specs:
        raise ValueError(f"{env_id} has no parameter {param!r}; known: {sorted(specs)}")
    grid = default_grid(specs[param]) if grid is None else np.asarray(grid, float)
    say = _say(progress)
    seeds = [TRAIN_SEED_OFFSET + 1000 * seed + k for k in range(n_train)]
    G, n = grid.size, len(seeds)
    t0 = time.perf_counter()
    world = cfg.make_world(seeds)
    bound = cfg.divergence_bound_m
    rmse, diverged, times = np.zeros(G), np.zeros(G, int), []
    for g, value in enumerate(grid):
        t_value = time.perf_counter()
        params = {s.name: np.full(n, s.default) for s in cls.PARAMS}
        params[param] = np.full(n, value)
        log = run_episodes(world, cfg.method, dtype=cfg.dtype, params=params)
        h = np.where(np.isfinite(log.horizontal_error), np.minimum(log.horizontal_error, bound), bound)
        h[log.diverged] = bound
        rmse[g], diverged[g] = np.sqrt((h ** 2).mean()), int(log.diverged.sum())
        times.append(time.perf_counter() - t_value)
        say(progress_line(param, value, g, G, rmse[g], diverged[g], n, times))
    best = int(np.argmin(rmse))
    out = {"env": env_id, "env_kwargs": env_kwargs, "method": cfg.method, "param": param,
           "fixed": {s.name: s.default for s in cls.PARAMS if s.name != param},
           "grid": grid.tolist(), "rmse_h_m": rmse.tolist(), "diverged": diverged.tolist(),
           "best": float(grid[best]), "best_rmse_h_m": float(rmse[best]), "train_seeds": seeds,
           "wall_time_s": time.perf_counter() - t0}
    done = (f"tuned {param} of {cfg.method} on {n} training episodes x {G} values in {out['wall_time_s']:.1f} s: "
            f"best {param} = {out['best']:.6g} (RMSE {out['best_rmse_h_m']:.3f} m)")
    print(done) if progress is True else say(done)  # the result on stdout, the progress on stderr
    return out


def _say(progress):
    """The callable that takes :func:`tune_fixed_parameter`'s lines (``progress``: False, True: stderr, or one)."""
    if callable(progress):
        return progress
    if progress:
        import sys
        return lambda line: print(line, file=sys.stderr, flush=True)
    return lambda line: None


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 90 else f"{s / 60:.0f} min" if s < 5400 else f"{s / 3600:.1f} h"


def progress_line(param: str, value: float, g: int, G: int, rmse: float, diverged: int, n: int, times: list) -> str:
    """The line of grid value ``g`` (0-based) of ``G``: its RMSE, its time and the ETA of the rest. The ETA
    averages the values after the first (the first pays the kernels' compilation on a first run); after the
    first value it says it will come."""
    div = f", {diverged} of {n} diverged" if diverged else ""
    line = f"tune: {param} = {value:.6g} ({g + 1}/{G}): RMSE {rmse:.3f} m{div} in {_duration(times[-1])}"
    left = G - g - 1
    if left == 0:
        return line
    if len(times) < 2:
        return line + "; ETA after the next value"
    return line + f"; ETA {_duration(left * float(np.mean(times[1:])))}"


def save_tuning(result: dict, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    from envs.outputs import write_atomic
    write_atomic(path, dumps(result, indent=2))
    return path


def load_tuning(path) -> dict:
    """Read a tuning result file (``FileNotFoundError`` / ``ValueError`` naming the file when unusable)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"tuning file not found: {path}")
    try:
        d = json.loads(path.read_bytes().decode("utf-8"))
        d["method"], d["param"], d["best"]
    except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, IndexError) as e:
        raise ValueError(f"{path}: not a tuning result file ({type(e).__name__}: {e})") from None
    if not isinstance(d["method"], str) or not isinstance(d["param"], str):
        raise ValueError(f"{path}: not a tuning result file ('method' and 'param' must be strings)")
    return d
