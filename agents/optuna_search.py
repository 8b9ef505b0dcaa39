"""``search: optuna`` of ``train.py sweep``: hyperparameter configurations proposed by Optuna's TPE sampler.

The search space is the sweep file's ``random`` ranges (``uniform`` / ``loguniform`` / ``randint`` ``[lo, hi]``,
``choice [...]``); the sampler is ``TPESampler(seed=search_seed)``, so a sweep rerun in a fresh folder proposes
the same configurations (TPE's first ``n_startup_trials`` = 10 proposals are seeded random draws; later ones
also depend on the results, which are reproducible from the trials' seeds). An Optuna trial is one
configuration, trained for every environment x scenario x algorithm x seed of the sweep (:func:`agents.sweep.
config_trials`); its objective is the mean of those runs' metric, maximized or minimized (``direction``).

* ``--backend local``: optuna's ask / tell loop, one configuration after another, in this process.
* ``--backend ray``: Ray Tune's ``OptunaSearch`` (``ray.tune.search.optuna``) proposes them, each a Ray Tune
  trial (at most ``--workers`` at once); with several at once, TPE proposals after the startup ones depend
  on which trials finished first.

Resuming: the configurations recorded in the ``trial.json`` files under the sweep folder whose runs all
finished are told to the sampler as finished trials with their objective (``study.add_trial``) and are not
trained again; recorded configurations with unfinished runs are proposed first again (``enqueue_trial``,
their finished runs kept); the sweep then asks for the rest of ``num_samples``. Both backends start from the
same study, built by :func:`prepare_study`.
"""
from __future__ import annotations

import functools
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

OPTUNA_INSTALL_HINT = "pip install 'navgym[distributed]' (or: pip install 'optuna>=3.4')"
OBJECTIVE = "objective"
"""The Ray Tune result key of a configuration's objective (the mean metric of its runs)."""


def require_optuna():
    """The ``optuna`` module, or ``ImportError`` with the one-line install hint."""
    try:
        import optuna
    except ImportError:
        raise ImportError(f"Optuna is not installed: {OPTUNA_INSTALL_HINT}") from None
    return optuna


def search_space(cfg) -> dict:
    """``{name: optuna distribution}`` of the sweep's ``random`` ranges."""
    from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution
    out = {}
    for k, d in cfg.random.items():
        if d.kind == "choice":
            out[k] = CategoricalDistribution(list(d.args))
        elif d.kind == "randint":
            out[k] = IntDistribution(*d.args)
        else:
            out[k] = FloatDistribution(float(d.args[0]), float(d.args[1]), log=d.kind == "loguniform")
    return out


@dataclass(frozen=True)
class Recorded:
    """A configuration found in the sweep folder: its number, values and (all runs finished) objective."""

    config_id: int
    params: dict
    value: float | None


def recorded_configs(cfg, root) -> list[Recorded]:
    """The configurations of the ``trial.json`` files under ``root`` that lie in the search space, by number;
    ``value`` is the mean metric of its runs when every run of it finished (else None)."""
    import optuna
    from agents.sweep import METRIC, config_trials, trial_status
    space = search_space(cfg)
    found: dict = {}
    for p in sorted(Path(root).rglob("trial.json")):
        try:
            t = json.loads(p.read_text())["trial"]
            params, cid = dict(t["searched"]), int(t["config_id"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if set(params) != set(space):
            continue  # another search space (the file was edited): not this sweep's configuration
        try:  # the values must lie in the ranges (create_trial checks them)
            optuna.trial.create_trial(params=params, distributions=space, value=0.0)
        except ValueError:
            continue
        key = json.dumps(params, sort_keys=True)
        if key not in found or cid < found[key][0]:
            found[key] = (cid, {k: params[k] for k in space})
    out = []
    for cid, params in sorted(found.values(), key=lambda x: x[0]):
        status = [trial_status(t) for t in config_trials(cfg, root, cid, params)]
        value = (sum(s["result"][METRIC] for s in status) / len(status)
                 if all(s is not None for s in status) else None)
        out.append(Recorded(cid, params, value))
    return out


def prepare_study(cfg, root, storage=None, study_name: str | None = None):
    """The Optuna study of a sweep (TPE sampler seeded from ``search_seed``), told the configurations that
    finished before (:func:`recorded_configs`) and with the unfinished ones enqueued.

    Returns ``(study, recorded, n_ask)``: ``recorded`` every :class:`Recorded` configuration found (finished:
    ``value`` not None), ``n_ask`` how many configurations to propose now (``num_samples`` minus the finished
    ones, at least 0)."""
    optuna = require_optuna()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    space = search_space(cfg)
    study = optuna.create_study(storage=storage, study_name=study_name,
                                sampler=optuna.samplers.TPESampler(seed=cfg.search_seed), direction=cfg.direction)
    recorded = recorded_configs(cfg, root)
    finished = [rec for rec in recorded if rec.value is not None]
    for rec in finished:
        study.add_trial(optuna.trial.create_trial(params=rec.params, distributions=space, value=rec.value))
    for rec in [rec for rec in recorded if rec.value is None][:max(0, cfg.num_samples - len(finished))]:
        study.enqueue_trial(rec.params)
    return study, recorded, max(0, cfg.num_samples - len(finished))


def _suggest(space: dict, trial) -> dict:
    """Ray Tune's define-by-run space: the suggested values, plus the Optuna trial number as ``config_id``."""
    for k, d in space.items():
        _suggest_one(trial, k, d)
    return {"config_id": trial.number}


def _suggest_one(trial, name: str, d):
    """``trial.suggest_*`` of distribution ``d`` (an enqueued trial returns its fixed value)."""
    from optuna.distributions import CategoricalDistribution, IntDistribution
    if isinstance(d, CategoricalDistribution):
        return trial.suggest_categorical(name, d.choices)
    if isinstance(d, IntDistribution):
        return trial.suggest_int(name, d.low, d.high)
    return trial.suggest_float(name, d.low, d.high, log=d.log)


def run_configuration(cfg, root, config: dict) -> dict:
    """Train every run of one configuration (``config``: the searched values and ``config_id``) and return
    ``{OBJECTIVE: mean metric, 'metrics': [each run's metric]}``; runs finished before are kept. Every run is
    tried; a failed run raises ``RuntimeError`` naming the failed run folders (after the others ran)."""
    from agents.sweep import METRIC, config_trials, run_trial
    params = {k: config[k] for k in cfg.random}
    metrics, errors = [], []
    for t in config_trials(cfg, root, int(config["config_id"]), params):
        try:
            metrics.append(run_trial(t)[METRIC])
        except Exception as e:  # the configuration fails; its other runs still train
            errors.append(f"{t.run_dir}: {type(e).__name__}: {e}")
    if errors:
        raise RuntimeError("; ".join(errors))
    return {OBJECTIVE: sum(metrics) / len(metrics), "metrics": metrics}


def describe_configuration(cfg, config: dict) -> str:
    """A configuration in a progress line: its number and the hyperparameters Optuna proposed."""
    from agents.sweep import _fmt
    hp = " ".join(f"{k}={_fmt(config[k])}" for k in cfg.random if k in config)
    cid = config.get("config_id")
    return (f"#{cid} " if cid is not None else "") + hp


def _rows(cfg, root, cid: int, params: dict, kept: dict, error: str | None):
    """The table rows of one configuration's runs after it ran (``kept``: run_dir -> record from before)."""
    from agents.sweep import METRIC, TrialRow, config_trials, trial_status
    rows = []
    for t in config_trials(cfg, root, cid, params):
        if kept.get(t.run_dir) is not None:
            rows.append(TrialRow(t, "kept", kept[t.run_dir]["result"][METRIC], None))
            continue
        done = trial_status(t)
        rows.append(TrialRow(t, "done", done["result"][METRIC], None) if done is not None
                    else TrialRow(t, "error", None, error or "RuntimeError: the run did not finish"))
    return rows


def _kept(cfg, root, cid, params) -> dict:
    from agents.sweep import config_trials, trial_status
    return {t.run_dir: trial_status(t) for t in config_trials(cfg, root, cid, params)}


def run_optuna(cfg, root, backend) -> list:
    """Run an Optuna sweep on ``backend`` (``local``: ask / tell here; ``ray``: Ray Tune's OptunaSearch);
    returns the table rows (:class:`agents.sweep.TrialRow`), configuration by configuration in the order the
    sampler proposed them, finished configurations from before first."""
    import optuna
    root = Path(root)
    rows = []
    storage = optuna.storages.InMemoryStorage()  # Ray Tune's OptunaSearch loads the study from it
    name = time.strftime("sweep-%Y%m%d-%H%M%S")
    study, recorded, n_ask = prepare_study(cfg, root, storage=storage, study_name=name)
    finished = [rec for rec in recorded if rec.value is not None]
    for rec in finished:
        rows += _rows(cfg, root, rec.config_id, rec.params, _kept(cfg, root, rec.config_id, rec.params), None)
    print(f"sweep: Optuna TPE (seed {cfg.search_seed}), {cfg.num_samples} configurations x "
          f"{len(cfg.envs) * len(cfg.scenarios) * len(cfg.algos) * len(cfg.seeds)} runs each; {len(finished)} "
          f"finished before (kept), proposing {n_ask} on {backend.name}", file=sys.stderr)
    if n_ask == 0:
        return rows
    space = search_space(cfg)
    from agents.backends import TrialProgress
    progress = TrialProgress(n_ask, functools.partial(describe_configuration, cfg), OBJECTIVE,
                             workers=backend.workers or 1, prefix="sweep: configuration")
    if backend.name != "ray":
        for _ in range(n_ask):
            trial = study.ask(space)
            params = {k: trial.params[k] for k in cfg.random}
            kept = _kept(cfg, root, trial.number, params)
            out, = backend.run_trials(functools.partial(run_configuration, cfg, str(root)),
                                      [{**params, "config_id": trial.number}], storage=root / "tune",
                                      progress=progress)
            if out.error is None:
                study.tell(trial, out.result[OBJECTIVE])
            else:
                study.tell(trial, state=optuna.trial.TrialState.FAIL)
            rows += _rows(cfg, root, trial.number, params, kept, out.error)
        return rows
    from ray.tune.search.optuna import OptunaSearch
    searcher = OptunaSearch(space=functools.partial(_suggest, space), metric=OBJECTIVE,
                            mode="max" if cfg.direction == "maximize" else "min",
                            sampler=study.sampler, storage=storage, study_name=name)
    kept_before = {}  # the finished runs of the unfinished configurations proposed again
    for rec in recorded:
        kept_before.update(_kept(cfg, root, rec.config_id, rec.params))
    outcomes = backend.run_search(functools.partial(run_configuration, cfg, str(root)), searcher, n_ask,
                                  storage=root / "tune", name=name, progress=progress)
    for o in sorted(outcomes, key=lambda o: o.config["config_id"]):
        params = {k: o.config[k] for k in cfg.random}
        rows += _rows(cfg, root, o.config["config_id"], params, kept_before, o.error)
    return rows
