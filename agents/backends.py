"""Where independent pieces of work run: in this process (``local``) or on Ray (``ray``).

Two operations, with the same meaning on both backends:

* :meth:`LocalBackend.map` / :meth:`RayBackend.map` -- ``fn(item)`` for every item, the results in the
  items' order, with a tqdm progress bar over completed items (eval.py's paired episode batches) whose rate
  and ETA leave out the first item (it pays the kernels' compilation on a first run). An
  exception raised by ``fn`` is raised again here, as itself (not wrapped in a Ray error).
* :meth:`RayBackend.run_search` -- Ray Tune trials whose configs a Tune searcher proposes (train.py sweep's
  ``search: optuna``; locally that search runs optuna's ask / tell loop over :meth:`LocalBackend.run_trials`).
* :meth:`LocalBackend.run_trials` / :meth:`RayBackend.run_trials` -- ``fn(config)`` for every trial config;
  each :class:`TrialOutcome` holds the returned result dict or the error that ended the trial, and a failing
  trial does not stop the others (train.py sweep's trials; on Ray they are Ray Tune trials).

``local`` runs everything in this process, in order. ``ray`` starts a local Ray in this process with
``num_cpus = workers`` (all cores without ``workers``), joins a running cluster with ``address``
(``'auto'`` or ``'HOST:6379'``, as ``ray start --head`` prints it), or uses the Ray this process has
already initialized. Functions and items are pickled to the workers: give module-level functions and
plain data (frozen dataclasses). The workers import navgym from the source tree this process imports it
from (``PYTHONPATH`` of the Ray job); on a cluster without a shared file system install navgym on every node.

Ray is an optional dependency (``pip install 'navgym[distributed]'``): :func:`require_ray` raises
:class:`BackendUnavailable` with the one-line install hint when it is missing.
"""
from __future__ import annotations

import functools
import os
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

BACKENDS = ("local", "ray")
"""The backend names of ``--backend``."""
RAY_INSTALL_HINT = "pip install 'navgym[distributed]' (or: pip install 'ray[tune]>=2.40,<3')"
SOURCE_ROOT = Path(__file__).resolve().parents[1]
"""The directory holding the ``agents``, ``envs``, ``nav_filters`` and ``earth`` packages this process runs."""


class BackendUnavailable(RuntimeError):
    """The requested backend cannot run here (Ray is not installed, or its cluster cannot be joined); the
    message says what to do."""


def require_ray():
    """The ``ray`` module, or :class:`BackendUnavailable` with the install hint."""
    try:
        import ray
    except ImportError:
        raise BackendUnavailable(f"--backend ray needs Ray, which is not installed: {RAY_INSTALL_HINT}") from None
    return ray


def ray_available() -> bool:
    """Whether Ray can be imported."""
    try:
        require_ray()
    except BackendUnavailable:
        return False
    return True


def check_backend_args(backend: str, address: str | None = None, workers: int | None = None) -> None:
    """``ValueError`` naming the argument for an unknown backend, ``--address`` / ``--workers`` without
    ``--backend ray`` or ``workers < 1``; :class:`BackendUnavailable` for ``ray`` without Ray installed, or an
    ``address`` where no cluster answers (:func:`probe_ray_address`, within :data:`RAY_PROBE_TIMEOUT_S`)."""
    if backend not in BACKENDS:
        raise ValueError(f"--backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if workers is not None and workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    if backend == "local":
        if address is not None:
            raise ValueError("--address joins a Ray cluster: it needs --backend ray")
        if workers is not None:
            raise ValueError("--workers sets the number of Ray workers: it needs --backend ray")
    else:
        if address is not None and not address.strip():
            raise ValueError("--address is empty (give 'auto' or HOST:PORT of the Ray head node)")
        require_ray()
        if address is not None:
            probe_ray_address(address)


@dataclass(frozen=True)
class TrialOutcome:
    """The end of one trial of :meth:`run_trials`.

    Attributes
    ----------
    config : the trial's config, as given.
    result : the dict the trial function returned, or None when it failed.
    error : ``'<ExceptionType>: <message>'`` of the exception that ended the trial, or None.
    """

    config: Any
    result: dict | None
    error: str | None


def error_text(exc: BaseException) -> str:
    """``'<ExceptionType>: <message>'`` of an exception (a Ray task error: of the exception it wraps)."""
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException):
        exc = cause
    return f"{type(exc).__name__}: {exc}"


FIRST_ITEM_FORMAT = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}, ETA after the first batch{postfix}]"
"""The progress bar's format until the first item is done: no rate and no ETA (it pays the kernels' compilation
on a first run, which would make any estimate minutes too long)."""


class TrialProgress:
    """The progress lines of :meth:`run_trials` / :meth:`run_search`: one when a trial starts and one when it
    ends (its metric or its error, its time and the ETA of the rest), each naming the trial by its
    hyperparameters (``describe(config)``); on Ray they replace Tune's own status tables, which stay quiet.

    Parameters
    ----------
    total : the trials to run.
    describe : ``describe(config) -> str``, the trial's name in its lines (module-level or a partial of one:
        Tune may pickle it with the run's settings).
    metric : the key of the trial result shown in its end line.
    workers : trials run at once (the ETA divides by it).
    prefix : the first word of every line.
    clock : seconds now (default: ``time.perf_counter``).

    The ETA averages the trials that ended, leaving the first out once another has ended (it pays the kernels'
    compilation on a first run); it is the time for the trials that have not ended, ``workers`` at once.
    """

    def __init__(self, total: int, describe: Callable[[Any], str] = str, metric: str | None = None,
                 workers: int = 1, prefix: str = "trial", clock: Callable[[], float] | None = None):
        self.total, self.describe, self.metric, self.workers, self.prefix = total, describe, metric, workers, prefix
        self.clock = clock  # seconds (default: time.perf_counter)
        self.started: dict = {}   # key -> (number, description, start time)
        self.times: list = []     # durations of the ended trials, in the order they ended

    def _now(self) -> float:
        if self.clock is not None:
            return self.clock()
        import time
        return time.perf_counter()

    def _say(self, line: str) -> None:
        from tqdm import tqdm
        tqdm.write(line, file=sys.stderr)  # above a progress bar, if any

    def start(self, key, config) -> None:
        """Trial ``key`` (any hashable: the config's position, Tune's trial id) starts with ``config``."""
        number = len(self.started) + 1
        self.started[key] = (number, self.describe(config), self._now())
        self._say(f"{self.prefix} {number}/{self.total} started: {self.started[key][1]}")

    def end(self, key, result: dict | None = None, error: str | None = None) -> str:
        """Trial ``key`` ended with ``result`` (a dict) or ``error`` (its text); returns the line it printed."""
        now = self._now()
        number, desc, t0 = self.started.get(key, (len(self.times) + 1, str(key), now))
        took = now - t0
        self.times.append(took)
        if error is not None:
            what = f"failed: {desc}: {error.splitlines()[0] if error else 'error'}"
        else:
            v = (result or {}).get(self.metric) if self.metric else None
            what = f"done: {desc}" + (f": {self.metric} {v:.4g}" if isinstance(v, (int, float)) else "")
        line = f"{self.prefix} {number}/{self.total} {what} in {_duration(took)}"
        left = self.total - len(self.times)
        if left > 0:
            base = self.times[1:] if len(self.times) > 1 else self.times
            line += f"; ETA {_duration(left * sum(base) / len(base) / max(1, self.workers))}"
        self._say(line)
        return line


def _duration(s: float) -> str:
    """A duration for a progress line: seconds, minutes or hours."""
    return f"{s:.0f} s" if s < 90 else f"{s / 60:.0f} min" if s < 5400 else f"{s / 3600:.1f} h"


def _tune_callback(progress: TrialProgress | None, key_of: Callable):
    """A Ray Tune callback that feeds ``progress`` (None: no callback) with its trials' starts and ends;
    ``key_of(trial)`` gives the key and the config :class:`TrialProgress` gets."""
    if progress is None:
        return []
    from ray.tune import Callback

    class Lines(Callback):
        def on_trial_start(self, iteration, trials, trial, **info):
            key, config = key_of(trial)
            progress.start(key, config)

        def on_trial_complete(self, iteration, trials, trial, **info):
            progress.end(key_of(trial)[0], result=_metrics_of(trial.last_result))

        def on_trial_error(self, iteration, trials, trial, **info):
            try:
                err = trial.get_pickled_error()
            except Exception:  # noqa: BLE001 - the line is a courtesy; the outcome keeps the error
                err = None
            progress.end(key_of(trial)[0], error=error_text(err) if err is not None else "the trial failed")
    return [Lines()]


def _metrics_of(result: dict | None) -> dict:
    return {k: v for k, v in (result or {}).items() if not _tune_bookkeeping(k)}


def _bar(total: int, desc: str | None, progress: bool, file=None):
    """The progress bar of :meth:`LocalBackend.map` / :meth:`RayBackend.map` (to ``file``, default stderr): its
    rate and ETA count from the end of the first item (:func:`_first_done`)."""
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit="batch", file=file or sys.stderr, dynamic_ncols=True,
                disable=not progress, mininterval=0.5, bar_format=FIRST_ITEM_FORMAT)


def _first_done(bar) -> None:
    """Count one item done and restart the bar's clock: from now on its rate and ETA leave out the first item
    (numba compiles the kernels during it on a first run), its elapsed time counts from here."""
    if bar.disable:
        bar.update(1)
        return
    bar.reset(bar.total)
    bar.n = bar.last_print_n = bar.initial = 1  # the rate counts the items after the first
    bar.bar_format = None
    bar.refresh()


def _advance(bar, first: bool) -> None:
    """One more item done: the first through :func:`_first_done`."""
    _first_done(bar) if first else bar.update(1)


class LocalBackend:
    """Everything in this process, in order."""

    name = "local"
    workers = 1

    def map(self, fn: Callable, items: Sequence, desc: str | None = None, label: Callable | None = None,
            progress: bool = True) -> list:
        """``[fn(item) for item in items]`` with a progress bar (``label(item)`` shown beside it)."""
        out = []
        with _bar(len(items), desc, progress) as bar:
            for item in items:
                if label is not None:
                    bar.set_postfix_str(label(item), refresh=True)
                out.append(fn(item))
                _advance(bar, first=len(out) == 1)
        return out

    def run_trials(self, fn: Callable[[Any], dict], configs: Sequence, storage: str | os.PathLike,
                   name: str = "trials", progress: TrialProgress | None = None) -> list[TrialOutcome]:
        """Each trial in turn; an exception ends that trial only (its traceback is printed to stderr).
        ``progress`` (:class:`TrialProgress`) prints a line as each trial starts and ends."""
        out = []
        for c in configs:
            key = object()
            if progress is not None:
                progress.start(key, c)
            try:
                out.append(TrialOutcome(c, dict(fn(c)), None))
            except Exception as e:  # a failing trial is reported and the others go on
                traceback.print_exc(file=sys.stderr)
                out.append(TrialOutcome(c, None, error_text(e)))
            if progress is not None:
                progress.end(key, out[-1].result, out[-1].error)
        return out

    def close(self) -> None:
        """Nothing to release."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class RayBackend:
    """Ray tasks (:meth:`map`) and Ray Tune trials (:meth:`run_trials`) on a local Ray or a cluster.

    Parameters
    ----------
    workers : at most this many tasks or trials run at once; a local Ray started here gets
        ``num_cpus = workers`` (default: every core of this machine; on a cluster: its CPUs).
    address : a running cluster to join (``'auto'``, ``'HOST:6379'``, ``'ray://HOST:10001'``); None starts a
        local Ray in this process (or uses the one this process already initialized).
    """

    name = "ray"

    def __init__(self, workers: int | None = None, address: str | None = None):
        ray = require_ray()
        self.workers = workers
        self.started = False
        if not ray.is_initialized():
            path = os.pathsep.join(filter(None, [str(SOURCE_ROOT), os.environ.get("PYTHONPATH")]))
            kw = dict(include_dashboard=False, logging_level="WARNING", log_to_driver=True,
                      runtime_env={"env_vars": {"PYTHONPATH": path}})
            if address is None:
                ray.init(num_cpus=workers or os.cpu_count(), **kw)
            else:
                probe_ray_address(address)
                try:
                    ray.init(address=address, **kw)
                except (ConnectionError, RuntimeError, ValueError) as e:
                    first = next((ln for ln in str(e).splitlines() if ln.strip()), type(e).__name__)
                    raise BackendUnavailable(
                        f"--address {address!r}: cannot join the Ray cluster ({first.strip()}); start it with "
                        "'ray start --head' and check the address and, with token authentication, the token "
                        "(RAY_AUTH_TOKEN)") from None
            self.started = True
        if self.workers is None:
            self.workers = max(1, int(ray.cluster_resources().get("CPU", 1)))

    def map(self, fn: Callable, items: Sequence, desc: str | None = None, label: Callable | None = None,
            progress: bool = True) -> list:
        """``fn(item)`` as one Ray task (1 CPU) per item, at most :attr:`workers` in flight; results in order.

        The first task that raises cancels the rest and its exception is raised here, unwrapped."""
        import ray
        from ray.exceptions import RayTaskError
        remote = ray.remote(num_cpus=1)(fn)
        results: list = [None] * len(items)
        pending: dict = {}
        todo = iter(enumerate(items))

        def submit():
            for i, item in todo:
                pending[remote.remote(item)] = i
                if len(pending) >= self.workers:
                    return

        n_done = 0
        with _bar(len(items), desc, progress) as bar:
            submit()
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    i = pending.pop(ref)
                    try:
                        results[i] = ray.get(ref)
                    except RayTaskError as e:
                        for other in pending:
                            ray.cancel(other)
                        cause = getattr(e, "cause", None)
                        if isinstance(cause, Exception):
                            raise cause from None
                        raise
                    if label is not None:
                        bar.set_postfix_str(label(items[i]), refresh=False)
                    n_done += 1
                    _advance(bar, first=n_done == 1)
                submit()
        return results

    def run_trials(self, fn: Callable[[Any], dict], configs: Sequence, storage: str | os.PathLike,
                   name: str = "trials", progress: TrialProgress | None = None) -> list[TrialOutcome]:
        """Each config as one Ray Tune trial (1 CPU, at most :attr:`workers` at once, no retry), the Tune
        experiment under ``storage/name``; a failing trial is recorded by Tune and the others go on. Tune's
        own output is quiet (``verbose=0``); ``progress`` (:class:`TrialProgress`) prints a line as each trial
        starts and ends, naming it by its config."""
        from ray import tune
        configs = list(configs)
        if not configs:
            return []

        def trial(config):
            return fn(configs[config["index"]])

        tuner = tune.Tuner(
            tune.with_resources(trial, {"cpu": 1}),
            param_space={"index": tune.grid_search(list(range(len(configs))))},
            tune_config=tune.TuneConfig(max_concurrent_trials=self.workers, reuse_actors=False),
            run_config=tune.RunConfig(name=name, storage_path=str(Path(storage).resolve()), verbose=0,
                                      callbacks=_tune_callback(progress, functools.partial(_indexed, configs)),
                                      failure_config=tune.FailureConfig(max_failures=0, fail_fast=False)))
        with _QuietTune():
            grid = tuner.fit()
        out: list = [None] * len(configs)
        for r in grid:
            i = r.config["index"]
            if r.error is not None:
                out[i] = TrialOutcome(configs[i], None, error_text(r.error))
            else:
                out[i] = TrialOutcome(configs[i], _metrics(r), None)
        for i, o in enumerate(out):
            if o is None:  # pragma: no cover - Tune reports every trial of a finished fit
                out[i] = TrialOutcome(configs[i], None, "RuntimeError: Ray Tune reported no result for this trial")
        return out

    def run_search(self, fn: Callable[[dict], dict], searcher, num_samples: int, storage: str | os.PathLike,
                   name: str = "search", progress: TrialProgress | None = None) -> list[TrialOutcome]:
        """``num_samples`` Ray Tune trials whose configs a Tune searcher proposes (``searcher``: a
        ``ray.tune.search.Searcher`` with its space, metric and mode set, e.g. ``OptunaSearch``), at most
        :attr:`workers` at once (1 CPU each, no retry), the experiment under ``storage/name``. Each trial runs
        ``fn(config)``; the outcomes hold the proposed config, in the order Tune created the trials; a failing
        trial is recorded and the others go on. Tune's own output is quiet; ``progress`` prints the lines."""
        from ray import tune
        from ray.tune.search import ConcurrencyLimiter
        if num_samples < 1:
            return []

        def trial(config):
            return fn(config)

        tuner = tune.Tuner(
            tune.with_resources(trial, {"cpu": 1}),
            tune_config=tune.TuneConfig(search_alg=ConcurrencyLimiter(searcher, max_concurrent=self.workers),
                                        num_samples=num_samples, reuse_actors=False),
            run_config=tune.RunConfig(name=name, storage_path=str(Path(storage).resolve()), verbose=0,
                                      callbacks=_tune_callback(progress, _proposed),
                                      failure_config=tune.FailureConfig(max_failures=0, fail_fast=False)))
        with _QuietTune():
            results = tuner.fit()
        return [TrialOutcome(dict(r.config), None, error_text(r.error)) if r.error is not None
                else TrialOutcome(dict(r.config), _metrics(r), None) for r in results]

    def close(self) -> None:
        """Shut Ray down if this backend started it (a Ray this process had initialized stays)."""
        if self.started:
            import ray
            ray.shutdown()
            self.started = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class _QuietTune:
    """While inside: Ray Tune's legacy console output, silent at ``verbose=0`` (its newer output prints an
    experiment table and result paths even then); the trials' lines come from :class:`TrialProgress`."""

    def __enter__(self):
        self.before = os.environ.get("RAY_AIR_NEW_OUTPUT")
        os.environ["RAY_AIR_NEW_OUTPUT"] = "0"
        return self

    def __exit__(self, *exc):
        if self.before is None:
            os.environ.pop("RAY_AIR_NEW_OUTPUT", None)
        else:
            os.environ["RAY_AIR_NEW_OUTPUT"] = self.before


def _indexed(configs: list, trial) -> tuple:
    """(key, config) of a Tune trial of :meth:`RayBackend.run_trials` (its config holds the index)."""
    i = trial.config["index"]
    return i, configs[i]


def _proposed(trial) -> tuple:
    """(key, config) of a Tune trial of :meth:`RayBackend.run_search` (the searcher's config)."""
    return trial.trial_id, dict(trial.config)


_TUNE_KEYS = {"timestamp", "checkpoint_dir_name", "done", "training_iteration", "trial_id", "date",
              "time_this_iter_s", "time_total_s", "pid", "hostname", "node_ip", "config", "time_since_restore",
              "iterations_since_restore", "experiment_tag"}


def _tune_bookkeeping(key: str) -> bool:
    """Whether a Tune result key is Tune's own bookkeeping rather than a metric the trial returned."""
    return key in _TUNE_KEYS


def _metrics(result) -> dict:
    """The dict a Tune trial function returned, from its ``ray.tune.Result`` (Tune's bookkeeping left out)."""
    return {k: v for k, v in (result.metrics or {}).items() if not _tune_bookkeeping(k)}


RAY_PROBE_TIMEOUT_S = 10.0
"""How long :func:`probe_ray_address` waits for a TCP connection to the cluster's address [s]."""


def probe_ray_address(address: str, timeout_s: float = RAY_PROBE_TIMEOUT_S) -> None:
    """:class:`BackendUnavailable` within ``timeout_s`` when nothing accepts a connection at the address
    ``ray.init(address=...)`` would connect to.

    ``ray.init`` retries an address where no cluster answers for minutes without a word (``127.0.0.1:1``: over
    400 s); a TCP connection to the same host and port (Ray's own resolution of ``'auto'`` and of a local
    address, :func:`ray._private.services.canonicalize_bootstrap_address`; ``ray://HOST:PORT`` as given)
    fails at once when nothing listens, or after ``timeout_s`` when the host does not answer. A port that
    accepts connections but is not a Ray cluster is not told apart here (``ray.init`` then reports it).
    ``'auto'`` without a running cluster is left to ``ray.init``, which says so at once."""
    import socket
    target = address.strip()
    if target.startswith("ray://"):
        target = target[len("ray://"):].split("/", 1)[0]
    else:
        try:
            from ray._private.services import canonicalize_bootstrap_address
            target = canonicalize_bootstrap_address(target)
        except Exception:  # noqa: BLE001 - Ray's own errors for this address come from ray.init, in one line
            return
        if target is None:
            return
    host, sep, port = target.rpartition(":")
    if not sep or not port.isdigit():
        raise BackendUnavailable(f"--address {address!r}: expected 'auto', HOST:PORT or ray://HOST:PORT")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as e:
        why = "no answer within {:g} s".format(timeout_s) if isinstance(e, TimeoutError) else (e.strerror or str(e))
        raise BackendUnavailable(f"--address {address!r}: no Ray cluster answers at {host}:{port} ({why}); start "
                                 "one with 'ray start --head' and give the address it prints") from None


def make_backend(backend: str = "local", address: str | None = None, workers: int | None = None):
    """A :class:`LocalBackend` or :class:`RayBackend` (use it as a context manager: Ray is shut down at the
    end when it was started here). Errors as :func:`check_backend_args`."""
    check_backend_args(backend, address, workers)
    if backend == "local":
        return LocalBackend()
    return RayBackend(workers=workers, address=address)
