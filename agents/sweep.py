"""``train.py sweep``: a grid / random search over training runs, each trial a ``train.py rl`` run.

A sweep file (YAML; every key but ``envs`` is optional; an example: ``configs/sweep.yml``)::

    envs: [GnssIns/SageHusa-v1]        # environment ids
    scenarios: [urban-transition]      # scenario names (env kwarg 'scenario'); omitted: the env's default
    algos: [ppo]                       # ppo, recurrentppo, sac, td3
    seeds: [0, 1]                      # training seeds: replicates of every hyperparameter configuration
    timesteps: 20000                   # env steps per trial
    n_envs: 16                         # rows of the native vector env (omitted: the algorithm's default)
    env_kwargs: {episode_length_s: 120}
    hyperparams: {n_epochs: 5}         # fixed algorithm arguments (RL Zoo names), every trial
    grid:                              # every combination of these values
      learning_rate: [3.0e-4, 1.0e-3]
    random:                            # drawn per configuration (uniform, loguniform: [lo, hi]; choice: [...];
      gamma: {uniform: [0.9, 0.99]}    #   randint: [lo, hi] inclusive)
    samples: 2                         # random configurations per grid point (default 1)
    search_seed: 0                     # seed of the random draws (search: optuna: of the TPE sampler)
    search: grid                       # grid (grid x random, above) or optuna (TPE over the `random` ranges)
    num_samples: 8                     # search: optuna: hyperparameter configurations to try
    direction: maximize                # search: optuna: maximize or minimize the metric (also picks the best)
    run_dir: "{scenario}/{algo}{hp}-s{seed}"   # run folder of a trial under --out ({env}, {scenario}, {algo},
                                       #   {seed}, {hp}: '-name=value_...' of the searched values, '' if none)
    eval: {episodes: 50, seed: 0, baselines: [sage-husa]}   # the eval.py command of the winners

Configurations are the grid points times ``samples`` random draws (drawn once, in order, from
``search_seed``: the same file gives the same trials); the trials are every environment x scenario x
algorithm x configuration x seed. A trial writes its usual ``train.py rl`` run folder (``model.zip``,
``config.json``, ``best/``, ``eval/``, ...) plus ``hyperparams.yml`` (its algorithm arguments, an RL Zoo file:
``train.py rl --config`` reruns it) and ``trial.json`` (status, the metric, or the error with its traceback).
With ``search: optuna`` (:mod:`agents.optuna_search`) the configurations are proposed one after another by
Optuna's TPE sampler (seeded from ``search_seed``: a rerun proposes the same ones) over the ``random``
ranges (``grid`` and ``samples`` are not used); each configuration is trained for every environment x
scenario x algorithm x seed and its objective is the mean metric of those runs.
The metric is the final held-out evaluation reward: the mean episode reward of the last ``EvalCallback``
evaluation on held-out world seeds (``eval_mean_reward_last`` of ``config.json``; higher is better).

A finished trial (``trial.json`` status ``done`` and its ``model.zip``) is never run again: rerunning an
interrupted sweep runs only the trials that have not finished (failed ones are retried). A failing trial is
reported with its error and the others go on (``train.py sweep`` then exits with status 1). The sweep writes ``sweep.csv``, ``sweep.md`` (every trial,
the best trial per environment x scenario x algorithm group, the eval.py command for the winners) and
``sweep.json`` under ``--out``.
"""
from __future__ import annotations

import csv
import io
import itertools
import json
import math
import shlex
import sys
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from envs.outputs import write_atomic

METRIC = "eval_mean_reward_last"
"""The trial metric: the mean reward of the last held-out evaluation during training (higher is better)."""
DISTRIBUTIONS = ("uniform", "loguniform", "choice", "randint")
SEARCHES = ("grid", "optuna")
"""``search`` of a sweep file: grid x random draws, or Optuna's TPE sampler over the ``random`` ranges."""
DIRECTIONS = ("maximize", "minimize")
_TOP_KEYS = {"envs", "scenarios", "algos", "seeds", "timesteps", "n_envs", "env_kwargs", "hyperparams", "grid",
             "random", "samples", "search_seed", "run_dir", "eval", "search", "num_samples", "direction"}
_EVAL_KEYS = {"episodes", "seed", "baselines"}
DEFAULT_RUN_DIR = "{env}/{scenario}/{algo}{hp}-s{seed}"


@dataclass(frozen=True)
class Distribution:
    """A random search dimension: ``uniform`` / ``loguniform`` ``[lo, hi]``, ``choice`` ``[v, ...]``,
    ``randint`` ``[lo, hi]`` (inclusive)."""

    kind: str
    args: tuple

    def __post_init__(self):
        if self.kind not in DISTRIBUTIONS:
            raise ValueError(f"distribution must be one of {', '.join(DISTRIBUTIONS)}, got {self.kind!r}")
        if self.kind == "choice":
            if len(self.args) < 1:
                raise ValueError("choice needs at least one value")
            return
        if len(self.args) != 2 or not all(isinstance(a, (int, float)) and not isinstance(a, bool)
                                          and math.isfinite(a) for a in self.args):
            raise ValueError(f"{self.kind} needs [lo, hi] (two finite numbers), got {list(self.args)}")
        lo, hi = self.args
        if not lo <= hi:
            raise ValueError(f"{self.kind} needs lo <= hi, got [{lo}, {hi}]")
        if self.kind == "loguniform" and lo <= 0:
            raise ValueError(f"loguniform needs lo > 0, got {lo}")
        if self.kind == "randint" and not all(isinstance(a, int) for a in self.args):
            raise ValueError(f"randint needs integer bounds, got {list(self.args)}")

    def sample(self, rng: np.random.Generator):
        """One value (a Python scalar)."""
        if self.kind == "choice":
            return self.args[int(rng.integers(len(self.args)))]
        lo, hi = self.args
        if self.kind == "uniform":
            return float(rng.uniform(lo, hi))
        if self.kind == "loguniform":
            return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        return int(rng.integers(lo, hi + 1))


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep file (see the module docstring); errors name the file and the field."""

    envs: tuple
    algos: tuple = ("ppo",)
    seeds: tuple = (0,)
    scenarios: tuple = (None,)
    timesteps: int = 100_000
    n_envs: int | None = None
    env_kwargs: dict = field(default_factory=dict)
    hyperparams: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    random: dict = field(default_factory=dict)
    samples: int = 1
    search_seed: int = 0
    run_dir: str = DEFAULT_RUN_DIR
    eval_episodes: int = 50
    eval_seed: int = 0
    eval_baselines: tuple = ("sage-husa",)
    search: str = "grid"
    num_samples: int | None = None
    direction: str = "maximize"
    source: str = "<sweep>"

    def _bad(self, name, msg):
        raise ValueError(f"{self.source}: {name}: {msg}")

    def __post_init__(self):
        import envs
        from agents.policies import ALGOS
        from agents.rollout import env_class
        for name in ("envs", "algos", "seeds", "scenarios"):
            v = getattr(self, name)
            if not isinstance(v, tuple) or not v:
                self._bad(name, f"must be a non-empty list, got {v!r}")
            if len(set(v)) != len(v):
                self._bad(name, f"lists a value twice: {list(v)}")
        for e in self.envs:
            if not envs.is_env_id(e):
                self._bad("envs", f"unknown environment {e!r}; known: {', '.join(sorted(envs.ENV_IDS))}")
        for a in self.algos:
            if not isinstance(a, str) or a.lower() not in ALGOS:
                self._bad("algos", f"unknown algorithm {a!r}; known: {', '.join(ALGOS)}")
        for s in self.seeds:
            if not (isinstance(s, int) and not isinstance(s, bool) and s >= 0):
                self._bad("seeds", f"must be integers >= 0, got {s!r}")
        for name, lo in (("timesteps", 1), ("samples", 1), ("eval_episodes", 1), ("search_seed", 0),
                         ("eval_seed", 0)):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= lo):
                self._bad(name.replace("eval_", "eval."), f"must be an integer >= {lo}, got {v!r}")
        if self.n_envs is not None and not (isinstance(self.n_envs, int) and self.n_envs >= 1):
            self._bad("n_envs", f"must be an integer >= 1, got {self.n_envs!r}")
        for name in ("env_kwargs", "hyperparams", "grid", "random"):
            if not isinstance(getattr(self, name), dict):
                self._bad(name, f"must be a mapping, got {getattr(self, name)!r}")
        if "scenario" in self.env_kwargs:
            self._bad("env_kwargs", "give the scenario under 'scenarios', not env_kwargs.scenario")
        for k, v in self.grid.items():
            if not isinstance(v, (list, tuple)) or not v:
                self._bad(f"grid.{k}", f"must be a non-empty list of values, got {v!r}")
        for k, d in self.random.items():
            if not isinstance(d, Distribution):
                self._bad(f"random.{k}", f"must be a distribution, got {d!r}")
        self._check_search()
        searched = list(self.grid) + list(self.random)
        both = (set(self.grid) & set(self.random)) | (set(searched) & set(self.hyperparams))
        if both:
            self._bad("grid/random/hyperparams", f"{sorted(both)} given in more than one of them")
        for e in self.envs:
            for s in self.scenarios:
                kw = dict(self.env_kwargs, **({} if s is None else {"scenario": s}))
                try:
                    env_class(e).config_from(kw)
                except ValueError as err:
                    self._bad("scenarios" if s is not None else "env_kwargs", str(err))
        try:
            self.run_dir.format(env="e", scenario="s", algo="a", hp="h", seed=0)
        except (KeyError, IndexError, ValueError) as err:
            self._bad("run_dir", f"{self.run_dir!r} is not a template of {{env}}, {{scenario}}, {{algo}}, {{hp}}, "
                                 f"{{seed}} ({err!r})")
        if "{seed}" not in self.run_dir:
            self._bad("run_dir", f"{self.run_dir!r} must contain {{seed}} (every seed is its own run)")
        from agents.methods import expand_method_spec
        for b in self.eval_baselines:
            if not isinstance(b, str):
                self._bad("eval.baselines", f"must be method specs of eval.py, got {b!r}")
            if ":" in b.split("[", 1)[0]:
                continue  # a file-based spec (tuned:, <algo>:): its file may be written after the sweep
            try:
                expand_method_spec(b, "open-sky")
            except (ValueError, FileNotFoundError) as err:
                self._bad("eval.baselines", str(err))


    def _check_search(self):
        """``search``, ``num_samples``, ``direction`` and the fields each search uses."""
        if self.search not in SEARCHES:
            self._bad("search", f"must be one of {', '.join(SEARCHES)}, got {self.search!r}")
        if self.direction not in DIRECTIONS:
            self._bad("direction", f"must be one of {', '.join(DIRECTIONS)}, got {self.direction!r}")
        if self.search == "grid":
            if self.num_samples is not None:
                self._bad("num_samples", "is the number of Optuna trials: it needs search: optuna "
                                         "(grid search: samples random draws per grid point)")
            return
        if not (isinstance(self.num_samples, int) and not isinstance(self.num_samples, bool)
                and self.num_samples >= 1):
            self._bad("num_samples", f"search: optuna needs an integer >= 1, got {self.num_samples!r}")
        if self.grid:
            self._bad("grid", "search: optuna takes its ranges from random (a list of values: choice: [...])")
        if self.samples != 1:
            self._bad("samples", "is the random draws per grid point of search: grid; search: optuna tries "
                                 "num_samples configurations")
        if not self.random:
            self._bad("random", "search: optuna needs at least one range to search (uniform, loguniform, "
                                "randint: [lo, hi]; choice: [...])")
        for k, d in self.random.items():
            if d.kind == "choice" and not all(v is None or isinstance(v, (bool, int, float, str)) for v in d.args):
                self._bad(f"random.{k}", f"search: optuna needs choice values that are numbers, strings, booleans "
                                         f"or null, got {list(d.args)}")
        from agents.optuna_search import OPTUNA_INSTALL_HINT, require_optuna
        try:
            require_optuna()
        except ImportError:
            self._bad("search", f"optuna needs Optuna, which is not installed: {OPTUNA_INSTALL_HINT}")


def _tuple(v, name, path):
    if v is None:
        raise ValueError(f"{path}: {name}: must be a non-empty list, got null")
    return tuple(v) if isinstance(v, list) else (v,)


def load_sweep(path) -> SweepConfig:
    """Read and validate a sweep file (``FileNotFoundError`` / ``ValueError`` naming the file and field)."""
    import yaml
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"sweep file not found: {path}")
    try:
        d = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ValueError(f"{path}: not valid YAML ({e})") from None
    if not isinstance(d, dict):
        raise ValueError(f"{path}: must be a mapping of sweep settings, got {type(d).__name__}")
    unknown = set(d) - _TOP_KEYS
    if unknown:
        raise ValueError(f"{path}: unknown key(s) {sorted(unknown)}; known: {sorted(_TOP_KEYS)}")
    if "envs" not in d:
        raise ValueError(f"{path}: envs: missing (a list of environment ids)")
    ev = d.get("eval") or {}
    if not isinstance(ev, dict) or set(ev) - _EVAL_KEYS:
        raise ValueError(f"{path}: eval: must be a mapping of {sorted(_EVAL_KEYS)}, got {ev!r}")
    random = {}
    for k, spec in (d.get("random") or {}).items():
        if not (isinstance(spec, dict) and len(spec) == 1):
            raise ValueError(f"{path}: random.{k}: must be one of {{{', '.join(DISTRIBUTIONS)}: [...]}}, got {spec!r}")
        (kind, args), = spec.items()
        try:
            random[k] = Distribution(kind, tuple(args) if isinstance(args, (list, tuple)) else (args,))
        except ValueError as e:
            raise ValueError(f"{path}: random.{k}: {e}") from None
    kw = dict(envs=_tuple(d["envs"], "envs", path), source=str(path), random=random)
    for name in ("algos", "seeds", "scenarios"):
        if name in d:
            kw[name] = _tuple(d[name], name, path)
    for name in ("timesteps", "n_envs", "samples", "search_seed", "run_dir", "search", "num_samples", "direction"):
        if name in d:
            kw[name] = d[name]
    if isinstance(kw.get("timesteps"), float) and kw["timesteps"].is_integer():
        kw["timesteps"] = int(kw["timesteps"])  # YAML reads 2e5 as a float
    for name in ("env_kwargs", "hyperparams", "grid"):
        if name in d:
            kw[name] = d[name] if d[name] is not None else {}
    if "episodes" in ev:
        kw["eval_episodes"] = ev["episodes"]
    if "seed" in ev:
        kw["eval_seed"] = ev["seed"]
    if "baselines" in ev:
        kw["eval_baselines"] = tuple(ev["baselines"] or ())
    return SweepConfig(**kw)


@dataclass(frozen=True)
class Trial:
    """One training run of a sweep.

    Attributes
    ----------
    env, scenario, algo, seed : what it trains (scenario None: the env's default).
    config_id : index of its hyperparameter configuration (grid point x random draw).
    searched : the searched hyperparameter values of that configuration.
    hyperparams : all algorithm arguments it passes (fixed + searched).
    env_kwargs : environment arguments (with the scenario).
    timesteps, n_envs : as ``train.py rl``.
    run_dir : the run folder, relative to the sweep folder; out : its absolute path.
    """

    env: str
    scenario: str | None
    algo: str
    seed: int
    config_id: int
    searched: dict
    hyperparams: dict
    env_kwargs: dict
    timesteps: int
    n_envs: int | None
    run_dir: str
    out: str

    @property
    def group(self) -> tuple:
        """(env, scenario, algo): the trials compared for the best one."""
        return (self.env, self.scenario or "default", self.algo)

    def describe(self) -> str:
        """The trial in a progress line: what it trains and its searched hyperparameters."""
        hp = " ".join(f"{k}={_fmt(v)}" for k, v in self.searched.items())
        return f"{self.env} {self.scenario or 'default'} {self.algo} seed {self.seed}" + (f" {hp}" if hp else "")

    def command(self) -> str:
        """The ``train.py rl`` command line of this trial."""
        args = ["python", "train.py", "rl", "--env", self.env, "--algo", self.algo, "--timesteps",
                str(self.timesteps), "--seed", str(self.seed)]
        if self.n_envs is not None:
            args += ["--n-envs", str(self.n_envs)]
        if self.env_kwargs:
            args += ["--env-kwargs", *(f"{k}={v}" for k, v in self.env_kwargs.items())]
        args += ["--config", str(Path(self.out) / "hyperparams.yml"), "--no-progress", "--out", self.out]
        return shlex.join(args)


def _fmt(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def configurations(cfg: SweepConfig) -> list[dict]:
    """The searched hyperparameter configurations: grid points (in order) x ``samples`` random draws."""
    rng = np.random.default_rng(cfg.search_seed)
    keys = list(cfg.grid)
    out = []
    for point in itertools.product(*(cfg.grid[k] for k in keys)):
        for _ in range(cfg.samples if cfg.random else 1):
            c = dict(zip(keys, point))
            c.update({k: d.sample(rng) for k, d in cfg.random.items()})
            out.append(c)
    return out


def _trial(cfg: SweepConfig, root: Path, env: str, scen, algo: str, cid: int, conf: dict, seed: int) -> Trial:
    """The trial training configuration ``conf`` (number ``cid``) of ``env`` x ``scen`` x ``algo`` x ``seed``."""
    hp = "".join(f"{'-' if i == 0 else '_'}{k}={_fmt(v)}" for i, (k, v) in enumerate(conf.items()))
    rel = cfg.run_dir.format(env=env.replace("/", "-"), scenario=scen or "default", algo=algo.lower(), hp=hp,
                             seed=seed)
    ekw = dict(cfg.env_kwargs, **({} if scen is None else {"scenario": scen}))
    return Trial(env=env, scenario=scen, algo=algo.lower(), seed=seed, config_id=cid, searched=dict(conf),
                 hyperparams={**cfg.hyperparams, **conf}, env_kwargs=ekw, timesteps=cfg.timesteps,
                 n_envs=cfg.n_envs, run_dir=rel, out=str(Path(root).resolve() / rel))


def _unique_folders(cfg: SweepConfig, trials: list[Trial]) -> list[Trial]:
    """``trials``, or ``ValueError`` naming ``run_dir`` when two share a folder."""
    seen = set()
    for t in trials:
        if t.run_dir in seen:
            raise ValueError(f"{cfg.source}: run_dir: {cfg.run_dir!r} gives two trials the same folder "
                             f"{t.run_dir!r}; add the fields that differ ({{env}}, {{scenario}}, {{algo}}, {{hp}})")
        seen.add(t.run_dir)
    return trials


def config_trials(cfg: SweepConfig, root, cid: int, conf: dict) -> list[Trial]:
    """The trials of one configuration: every environment x scenario x algorithm x seed (the runs an Optuna
    trial trains; ``ValueError`` when two share a folder)."""
    return _unique_folders(cfg, [_trial(cfg, root, env, scen, algo, cid, conf, seed) for env, scen, algo, seed
                                 in itertools.product(cfg.envs, cfg.scenarios, cfg.algos, cfg.seeds)])


def expand_trials(cfg: SweepConfig, root) -> list[Trial]:
    """Every trial of a grid sweep, run folders under ``root`` (``ValueError`` when two share a folder). For
    ``search: optuna``, whose configurations are proposed while it runs: the trials of one configuration of
    the ``random`` ranges' lower ends / first choices (it checks the run folder template)."""
    if cfg.search == "optuna":
        return config_trials(cfg, root, 0, {k: d.args[0] for k, d in cfg.random.items()})
    return _unique_folders(cfg, [
        _trial(cfg, root, env, scen, algo, cid, conf, seed) for env, scen, algo, (cid, conf), seed
        in itertools.product(cfg.envs, cfg.scenarios, cfg.algos, enumerate(configurations(cfg)), cfg.seeds)])


def trial_status(trial: Trial) -> dict | None:
    """The record of a finished trial, else None: its ``trial.json`` with status ``done`` (and its
    ``model.zip``), or, without ``trial.json``, a run folder that ``train.py rl`` finished with the trial's
    settings (``config.json`` with the metric; environment, algorithm, seed, steps, rows, environment and
    algorithm arguments all equal)."""
    out = Path(trial.out)
    if not (out / "model.zip").is_file():
        return None
    try:
        rec = json.loads((out / "trial.json").read_text())
    except FileNotFoundError:
        rec = None
    except (OSError, ValueError):
        return None
    if rec is not None:
        return rec if rec.get("status") == "done" else None
    try:
        cfg = json.loads((out / "config.json").read_text())
    except (OSError, ValueError):
        return None
    same = (cfg.get("env") == trial.env and cfg.get("algo") == trial.algo and cfg.get("seed") == trial.seed
            and cfg.get("n_timesteps") == trial.timesteps and cfg.get("env_kwargs") == trial.env_kwargs
            and (trial.n_envs is None or cfg.get("n_envs") == trial.n_envs)
            and all(cfg.get("hyperparameters", {}).get(k) == v for k, v in trial.hyperparams.items())
            and "wall_time_s" in cfg and METRIC in cfg)
    if not same:
        return None
    return {"status": "done", "result": _result(cfg)}


def _result(cfg: dict) -> dict:
    """A trial's result from its run's ``config.json``."""
    return {METRIC: cfg[METRIC], "eval_mean_reward_best": cfg.get("eval_mean_reward_best"),
            "n_timesteps": cfg["n_timesteps"], "wall_time_s": cfg["wall_time_s"]}


def run_trial(trial: Trial) -> dict:
    """Train one trial (``train.py rl`` with its settings) and return ``{METRIC, ...}``; writes
    ``hyperparams.yml`` and ``trial.json`` into its run folder. A finished trial returns its recorded result.
    An exception is recorded in ``trial.json`` (error and traceback) and raised again."""
    done = trial_status(trial)
    if done is not None:
        return done["result"]
    import yaml
    out = Path(trial.out)
    out.mkdir(parents=True, exist_ok=True)
    rec = {"status": "running", "trial": asdict(trial), "command": trial.command(), "started": time.time()}
    write_atomic(out / "trial.json", json.dumps(rec, indent=2, default=str))
    try:
        from agents.training import train_rl
        write_atomic(out / "hyperparams.yml", yaml.safe_dump({trial.env: dict(trial.hyperparams)}, sort_keys=False))
        cfg = train_rl(trial.env, trial.algo, out, timesteps=trial.timesteps, seed=trial.seed, n_envs=trial.n_envs,
                       env_kwargs=dict(trial.env_kwargs), config_file=out / "hyperparams.yml", progress=False)
        if METRIC not in cfg:
            raise RuntimeError(f"{out}: training wrote no held-out evaluation ({out / 'eval' / 'evaluations.npz'})")
        result = _result(cfg)
    except Exception as e:
        rec.update(status="error", error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())
        write_atomic(out / "trial.json", json.dumps(rec, indent=2, default=str))
        raise
    rec.update(status="done", result=result)
    write_atomic(out / "trial.json", json.dumps(rec, indent=2, default=str))
    return result


@dataclass(frozen=True)
class TrialRow:
    """A trial's line of the sweep table: ``status`` is ``done`` (trained now), ``kept`` (finished before,
    not rerun) or ``error``."""

    trial: Trial
    status: str
    metric: float | None
    error: str | None


def run_sweep(cfg: SweepConfig, root, backend) -> list[TrialRow]:
    """Run the trials that have not finished on ``backend`` (:mod:`agents.backends`), then write the tables
    (:func:`write_tables`). Returns one row per trial, in the order of :func:`expand_trials`."""
    root = Path(root)
    if cfg.search == "optuna":
        from agents.optuna_search import run_optuna
        rows = run_optuna(cfg, root, backend)
        write_tables(cfg, root, rows)
        return rows
    trials = expand_trials(cfg, root)
    kept = {t.run_dir: trial_status(t) for t in trials}
    pending = [t for t in trials if kept[t.run_dir] is None]
    print(f"sweep: {len(trials)} trials, {len(trials) - len(pending)} finished before (kept), running "
          f"{len(pending)} on {backend.name}", file=sys.stderr)
    name = time.strftime("sweep-%Y%m%d-%H%M%S")
    from agents.backends import TrialProgress
    progress = TrialProgress(len(pending), Trial.describe, METRIC, workers=backend.workers or 1, prefix="sweep: trial")
    outcomes = {o.config.run_dir: o for o in backend.run_trials(run_trial, pending, storage=root / "tune", name=name,
                                                                progress=progress)}
    rows = []
    for t in trials:
        if kept[t.run_dir] is not None:
            rows.append(TrialRow(t, "kept", kept[t.run_dir]["result"][METRIC], None))
        else:
            o = outcomes[t.run_dir]
            rows.append(TrialRow(t, "error", None, o.error) if o.error else TrialRow(t, "done", o.result[METRIC], None))
    write_tables(cfg, root, rows)
    return rows


def best_per_group(rows: list[TrialRow], direction: str = "maximize") -> dict:
    """``{(env, scenario, algo): the finished row with the highest metric}`` (the lowest with ``direction``
    ``minimize``; groups without a finished row left out)."""
    best: dict = {}
    sign = 1.0 if direction == "maximize" else -1.0
    for r in rows:
        if r.metric is None:
            continue
        g = r.trial.group
        if g not in best or sign * r.metric > sign * best[g].metric:
            best[g] = r
    return best


def _display(path: str) -> str:
    """A path relative to the working directory when it lies under it."""
    try:
        return str(Path(path).relative_to(Path.cwd()))
    except ValueError:
        return path


def eval_commands(cfg: SweepConfig, root, rows: list[TrialRow]) -> list[str]:
    """One ``eval.py`` command per scenario: the baselines and each group's best model on held-out episodes
    (paths relative to the working directory where they lie under it)."""
    from agents.rollout import env_class
    per_scen: dict = {}
    for (env, _, algo), r in best_per_group(rows, cfg.direction).items():
        scen = r.trial.scenario or env_class(env).config_from({}).scenario
        per_scen.setdefault(str(scen), []).append(f"{algo}:{_display(str(Path(r.trial.out) / 'model.zip'))}")
    script = _display(str(Path(__file__).resolve().parents[1] / "eval.py"))
    cmds = []
    for scen, models in per_scen.items():
        methods = ",".join([*cfg.eval_baselines, *models])
        out = _display(str(Path(root).resolve() / "eval" / scen))
        cmds.append(shlex.join(["python", script, "--scenario", scen, "--methods", methods, "--episodes",
                                str(cfg.eval_episodes), "--seed", str(cfg.eval_seed), "--out", out]))
    return cmds


FIELDS = ("run_dir", "env", "scenario", "algo", "seed", "config_id", "searched", "status", METRIC, "error")


def _row_dict(r: TrialRow) -> dict:
    t = r.trial
    return {"run_dir": t.run_dir, "env": t.env, "scenario": t.scenario or "default", "algo": t.algo, "seed": t.seed,
            "config_id": t.config_id, "searched": " ".join(f"{k}={_fmt(v)}" for k, v in t.searched.items()),
            "status": r.status, METRIC: r.metric, "error": r.error}


def write_tables(cfg: SweepConfig, root, rows: list[TrialRow]) -> None:
    """``sweep.csv`` (a line per trial), ``sweep.md`` (trials, best per group, eval commands, errors) and
    ``sweep.json`` under ``root``."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    dicts = [_row_dict(r) for r in rows]
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=FIELDS)
    w.writeheader()
    w.writerows(dicts)
    write_atomic(root / "sweep.csv", buf.getvalue())
    best = best_per_group(rows, cfg.direction)
    cmds = eval_commands(cfg, root, rows)

    def cell(v):
        return "" if v is None else f"{v:.4g}" if isinstance(v, float) else str(v).replace("|", "\\|")
    n_err = sum(r.status == "error" for r in rows)
    better = "higher" if cfg.direction == "maximize" else "lower"
    lines = [f"# Sweep `{cfg.source}`", "",
             f"{len(rows)} trials ({sum(r.status == 'done' for r in rows)} trained now, "
             f"{sum(r.status == 'kept' for r in rows)} finished before and kept, {n_err} failed). Metric "
             f"`{METRIC}`: mean episode reward of the last held-out evaluation during training ({better} is better)"
             + (f"; configurations proposed by Optuna's TPE sampler (seed {cfg.search_seed})."
                if cfg.search == "optuna" else "."),
             "", "| " + " | ".join(FIELDS[:-1]) + " |", "|" + "---|" * (len(FIELDS) - 1)]
    lines += ["| " + " | ".join(cell(d[k]) for k in FIELDS[:-1]) + " |" for d in dicts]
    lines += ["", "## Best trial per group", "", "| env | scenario | algo | run_dir | searched | " + METRIC + " |",
              "|---|---|---|---|---|---|"]
    lines += [f"| {g[0]} | {g[1]} | {g[2]} | {r.trial.run_dir} | {cell(_row_dict(r)['searched'])} | "
              f"{r.metric:.4g} |" for g, r in best.items()]
    lines += ["", "## Evaluate the winners", "", "```bash", *cmds, "```"]
    if n_err:
        lines += ["", "## Failed trials", ""]
        lines += [f"- `{r.trial.run_dir}`: {r.error} (traceback: `{r.trial.run_dir}/trial.json`)"
                  for r in rows if r.status == "error"]
    write_atomic(root / "sweep.md", "\n".join(lines) + "\n")
    write_atomic(root / "sweep.json", json.dumps(
        {"source": cfg.source, "metric": METRIC, "trials": dicts, "eval_commands": cmds,
         "best": [{"group": list(g), "run_dir": r.trial.run_dir, METRIC: r.metric} for g, r in best.items()]},
        indent=2, default=str))
