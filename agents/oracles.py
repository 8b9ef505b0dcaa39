"""Hindsight oracles of an environment's knob: how much any policy in its action space could win.

An RL benchmark without measured headroom tells its users nothing. These oracles
choose the env's own action (the Sage-Husa ``b``, the strong-tracking softening,
the MA-STKF pair) *knowing the truth*, so their errors bound from below what a
policy acting on the same knob can reach (up to the grid and the greediness):

* :func:`greedy_schedule` -- hindsight-greedy schedule: per segment, the episode's filter is
  branched into K copies (one per candidate action), each runs the segment and a lookahead with its
  action, and the branch with the lowest squared horizontal error over segment + lookahead is kept.
* :func:`best_per_episode` -- the best constant action of each episode in hindsight.
* :func:`crossfit_schedule` -- one time-indexed schedule shared by all episodes, fitted (greedily, as
  above, on the pooled error) on one half of the episodes and scored on the other half, and vice versa:
  what a policy could win by memorizing *when* the scenario's events happen, without seeing the episode.

Luck: a hindsight choice among K branches wins something even where nothing is to be won (the branch
that happened to draw the smaller errors). Evaluate the same oracle on a scenario without events
(``open-sky``, the placebo) and subtract (eval.py ``--headroom`` does).

Everything runs through the env core (:class:`envs.core.TuningCore`, branching with
:meth:`~envs.core.TuningCore.copy_rows`), so what an oracle finds replays exactly through the
environment: ``run_policy_episodes(env_id, env_kwargs, ScheduledPolicy(result.actions), seeds)``
reproduces ``result.log`` bit for bit.

Candidate actions (:func:`action_grid`): ``n`` values (default 7) spanning [-1, 1] per action
component; the full product for 1-D and 2-D actions (7 or 49 candidates); beyond two components one
component at a time with the others at the env's default action (``1 + k (n - 1)`` candidates, or
fewer where the default lies on the grid). An explicit (K, k) array of actions may be given instead.

The cost of an oracle is counted in *episode-equivalents* (one episode of the env run once):
``K (segment + lookahead) / segment`` for :func:`greedy_schedule` (e.g. 7 x 3 = 21 for 10 s segments
with a 20 s lookahead), ``K`` for :func:`best_per_episode`, and ``K (segment + lookahead) / segment + 1``
for :func:`crossfit_schedule`; ``result.details['episode_equivalents']`` holds the measured figure.
"""
from __future__ import annotations

import itertools
import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from envs.core import TuningCore
from envs.episodes import EpisodeLog, concat_logs
from envs.gnss_ins_env import make_config

from .policies import ScheduledPolicy
from .rollout import core_episode_log, env_class, run_policy_episodes

DEFAULT_GRID_N = 7
"""Candidate values per action component of the default grid."""
BATCH_ROWS = 256
"""Rows (episodes x candidates) per batched core of :func:`greedy_schedule` / :func:`best_per_episode`."""


@dataclass(frozen=True)
class OracleResult:
    """What an oracle chose and the errors of its chosen path.

    Attributes
    ----------
    kind : ``'greedy-schedule'``, ``'best-per-episode'`` or ``'crossfit-schedule'``.
    env_id : the environment.
    seeds : (E,) world seeds of the episodes.
    grid : (K, k) candidate actions.
    actions : (E, M, k) the action of every episode at every epoch (replay with
        :class:`agents.policies.ScheduledPolicy`).
    log : :class:`envs.episodes.EpisodeLog` of the chosen path (E episodes).
    details : kind-specific figures: ``segment_epochs``, ``lookahead_epochs``, ``choices`` (candidate indices
        per episode and segment), ``branch_cost_m2`` (E, S, K) sums of squared horizontal error over segment
        + lookahead of every branch, ``episode_equivalents``, ``wall_time_s``, ...
    """

    kind: str
    env_id: str
    seeds: tuple
    grid: np.ndarray
    actions: np.ndarray
    log: EpisodeLog
    details: dict

    def rmse_h_m(self, bound: float = np.inf) -> np.ndarray:
        """(E,) horizontal RMSE of each episode [m], errors clipped at ``bound`` (non-finite count as it)."""
        return episode_rmse(self.log, bound)


def episode_rmse(log: EpisodeLog, bound: float = np.inf) -> np.ndarray:
    """(E,) horizontal RMSE of each episode of ``log`` [m], errors clipped at ``bound`` as the env core scores
    them (a non-finite error counts as ``bound``)."""
    h = log.horizontal_error
    h = np.where(np.isfinite(h), np.minimum(h, bound), bound)
    return np.sqrt(np.mean(h ** 2, axis=1))


# --------------------------------------------------------------------------- inputs
def action_grid(specs, n: int = DEFAULT_GRID_N) -> np.ndarray:
    """(K, k) candidate actions of an env with parameter ``specs`` (see the module docstring).

    Parameters
    ----------
    specs : the env's :class:`envs.config.ParamSpec` tuple (k components).
    n : values per component, ``np.linspace(-1, 1, n)`` (an int >= 2).
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n (candidate values per action component) must be an int >= 2, got {n!r}")
    k = len(specs)
    vals = np.linspace(-1.0, 1.0, int(n))
    if k <= 2:
        return np.array(list(itertools.product(vals, repeat=k)), np.float64)
    default = np.array([s.to_action(s.default) for s in specs], np.float64)
    rows = [default]
    for i in range(k):
        for v in vals:
            a = default.copy()
            a[i] = v
            if not any(np.array_equal(a, r) for r in rows):
                rows.append(a)
    return np.array(rows)


def resolve_grid(grid, specs) -> np.ndarray:
    """The (K, k) candidate actions for ``grid``: an int (values per component, :func:`action_grid`) or an
    explicit array of actions ((K, k), or (K,) for a 1-D action); ``ValueError`` naming ``grid`` otherwise."""
    if isinstance(grid, (int, np.integer)) and not isinstance(grid, bool):
        return action_grid(specs, int(grid))
    k = len(specs)
    a = np.array(grid, np.float64)
    if a.ndim == 1 and k == 1:
        a = a[:, None]
    if a.ndim != 2 or a.shape[1] != k or a.shape[0] < 1:
        raise ValueError(f"grid must be an int or an array of actions of shape (K, {k}), got shape {a.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.abs(a) <= 1.0)):
        raise ValueError("grid actions must be finite and within [-1, 1]")
    return a


def _epochs(seconds, rate_hz: float, name: str, minimum: int) -> int:
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not math.isfinite(seconds) or (
            seconds < 0 if minimum == 0 else seconds <= 0):
        raise ValueError(f"{name} must be a {'non-negative' if minimum == 0 else 'positive'} finite number of "
                         f"seconds, got {seconds!r}")
    return max(minimum, int(round(seconds * rate_hz)))


def _setup(env_id, env_kwargs, seeds, grid):
    cls = env_class(env_id)
    if not cls.PARAMS:
        raise ValueError(f"{env_id} acts per receiver channel: its schedule oracle is not implemented")
    env_kwargs = dict(env_kwargs or {})
    cfg = make_config(cls.DEFAULTS, env_kwargs)
    from envs.core import check_method_has_params
    check_method_has_params(cfg.method, cls.PARAMS, cls.DEFAULTS["method"])
    if cfg.zupt not in ("none", "truth"):
        raise ValueError(f"the oracles branch the filter state, which the {cfg.zupt!r} zero-velocity detector's "
                         "stream state does not allow: use zupt='none' (or 'truth')")
    seeds = tuple(int(s) for s in seeds)
    if not seeds:
        raise ValueError("seeds is empty")
    return cls, env_kwargs, cfg, seeds, resolve_grid(grid, cls.PARAMS)


def _reporter(progress):
    """A ``report(message)`` for ``progress``: None/False silent, True one rewritten stderr line, or a callable."""
    if callable(progress):
        return progress
    if not progress:
        return lambda msg, done=False: None

    def report(msg, done=False):
        print(f"\r{msg:<78s}", end="\n" if done else "", file=sys.stderr, flush=True)
    return report


# --------------------------------------------------------------------------- the branch search
def _branch_search(cfg, specs, seeds, grid, seg: int, look: int, pooled: bool, report, label: str):
    """Greedy branch search on one batch: rows ``e * K + k`` run episode ``seeds[e]`` with candidate ``k``.

    Per segment ``[s0, s1)``: every row runs the segment and the lookahead ``[s1, s2)`` with its candidate;
    the core is returned to its state at ``s1`` (a :meth:`TuningCore.clone` taken there) and the rows of
    each episode are overwritten with its best branch (``pooled``: the candidate with the lowest cost summed
    over all episodes, for all of them). Returns ``(core, rows, chosen (E, M, k), details, step rows)``.
    """
    E, K = len(seeds), grid.shape[0]
    B = E * K
    core = TuningCore(cfg, specs, B)
    core.reset_rows(np.arange(B), [s for s in seeds for _ in range(K)])
    M, bound = core.M, cfg.divergence_bound_m
    act = np.tile(grid, (E, 1))
    rec = {"nis": np.zeros((B, M)), "nsat": np.zeros((B, M), int), "zupt": np.zeros((B, M), bool),
           "term": np.zeros((B, M), bool)}
    chosen = np.zeros((E, M, grid.shape[1]))
    choices, costs = [], []
    n_seg = -(-M // seg)
    stepped = 0
    for i, s0 in enumerate(range(0, M, seg)):
        s1, cost = min(s0 + seg, M), np.zeros(B)
        s2 = min(s1 + look, M)
        snap = None
        for j in range(s0, s2):
            if j == s1:
                snap = core.clone()
            r = core.step(act)
            h, div = r.info["horizontal_error_m"], r.info["diverged"]
            cost += np.where(div | ~np.isfinite(h), bound, np.minimum(h, bound)) ** 2
            if j < s1:
                rec["nis"][:, j], rec["nsat"][:, j] = r.info["nis_pr"], r.info["n_sats"]
                rec["zupt"][:, j], rec["term"][:, j] = r.info["zupt"], r.terminated
        stepped += s2 - s0
        c = cost.reshape(E, K)
        best = np.full(E, int(np.argmin(c.sum(0)))) if pooled else np.argmin(c, axis=1)
        if snap is not None:
            core = snap
        src = np.repeat(np.arange(E) * K + best, K)
        core.copy_rows(np.arange(B), src)
        for v in rec.values():
            v[:, s0:s1] = v[src, s0:s1]
        chosen[:, s0:s1] = grid[best][:, None, :]
        choices.append(best)
        costs.append(c)
        report(f"{label}, segment {i + 1}/{n_seg} ({K} branches each)")
    rows = np.arange(E) * K
    details = {"choices": np.stack(choices, 1), "branch_cost_m2": np.stack(costs, 1), "stepped_epochs": stepped,
               "rec": {k: v[rows] for k, v in rec.items()}}
    return core, rows, chosen, details


def _search(env_id, env_kwargs, seeds, grid, seg_s, look_s, kind, batch_rows, progress, whole_episode=False,
            pooled=False):
    """Run :func:`_branch_search` over chunks of episodes (one chunk when ``pooled``) -> OracleResult."""
    cls, env_kwargs, cfg, seeds, grid = _setup(env_id, env_kwargs, seeds, grid)
    rate = cfg.resolve_scenario().gnss_rate_hz
    M_hint = None
    if whole_episode:
        seg, look = 10 ** 9, 0
    else:
        seg = _epochs(seg_s, rate, "segment_s", 1)
        look = _epochs(look_s, rate, "lookahead_s", 0)
    if isinstance(batch_rows, bool) or not isinstance(batch_rows, (int, np.integer)) or batch_rows < 1:
        raise ValueError(f"batch_rows must be a positive int, got {batch_rows!r}")
    K = grid.shape[0]
    per = len(seeds) if pooled else max(1, int(batch_rows) // K)
    report = _reporter(progress)
    t0 = time.perf_counter()
    logs, acts, det = [], [], []
    for c0 in range(0, len(seeds), per):
        chunk = seeds[c0:c0 + per]
        label = f"{kind}: episodes {c0 + 1}-{c0 + len(chunk)}/{len(seeds)}"
        core, rows, chosen, d = _branch_search(cfg, cls.PARAMS, chunk, grid, seg, look, pooled, report, label)
        M_hint = core.M
        rec = d.pop("rec")
        logs.append(core_episode_log(core, rows, rec["nis"], rec["nsat"], rec["zupt"], rec["term"].any(1), 0.0))
        acts.append(chosen)
        det.append(d)
    wall = time.perf_counter() - t0
    log = concat_logs(logs)
    log = EpisodeLog(**{**{f: getattr(log, f) for f in EpisodeLog.__dataclass_fields__}, "filter_time_s": wall})
    seg = min(seg, M_hint)
    details = {"segment_epochs": seg, "lookahead_epochs": look,
               "choices": np.concatenate([d["choices"] for d in det], 0),
               "branch_cost_m2": np.concatenate([d["branch_cost_m2"] for d in det], 0),
               "episode_equivalents": K * sum(d["stepped_epochs"] for d in det) / (M_hint * len(det)),
               "wall_time_s": wall, "pooled": pooled}
    report(f"{kind}: {len(seeds)} episodes x {K} branches in {wall:.1f} s "
           f"({details['episode_equivalents']:.1f} episode-equivalents each)", done=True)
    return OracleResult(kind, env_id, seeds, grid, np.concatenate(acts, 0), log, details), env_kwargs


# --------------------------------------------------------------------------- public oracles
def greedy_schedule(env_id: str, env_kwargs: dict | None, seeds, segment_s: float = 10.0,
                    lookahead_s: float = 20.0, grid=DEFAULT_GRID_N, batch_rows: int = BATCH_ROWS,
                    progress=None) -> OracleResult:
    """Hindsight-greedy schedule of the env's parameters, per episode.

    Per segment of ``segment_s`` (rounded to whole GNSS epochs), K copies of each episode's filter state are
    branched (rows = episodes x K candidate actions, :func:`action_grid`), every branch runs the segment and
    ``lookahead_s`` more with its action, the branch with the lowest sum of squared horizontal error over
    segment + lookahead (errors clipped at the divergence bound) is kept: the state at the segment's end of
    that branch is restored on all K rows and the search continues. The last segments' lookahead is cut at
    the episode's end.

    Cost: ``K (segment + lookahead) / segment`` episode-equivalents per episode (21 for the defaults and a
    1-D action; 147 for the 49 candidates of a 2-D action), plus one snapshot of the filter state per
    segment. Measured on 2 shared cores, noise-burst, 8 episodes: ``GnssIns/SageHusa-v1`` (7 candidates)
    60 s episodes 4.3 s (17.5 episode-equivalents: the last segments' lookahead is cut), 300 s episodes
    22 s (20.3; one plain batched run of the 8 episodes: 1.7 s); ``GnssIns/MASTKF-v1`` (49 candidates) 60 s
    episodes 23 s (122.5).

    Parameters
    ----------
    env_id : a registered id (its parameters, defaults and default method).
    env_kwargs : :class:`envs.config.EnvConfig` fields (scenario, episode_length_s, method, dtype, ...);
        ``zupt`` must be ``'none'`` or ``'truth'``.
    seeds : (E,) world seeds.
    segment_s : decision interval [s] (> 0).
    lookahead_s : further time each branch runs with its action before the choice [s] (>= 0).
    grid : candidate values per action component (int), or the (K, k) candidate actions.
    batch_rows : rows (episodes x K) per batched core (memory: the world of every row is held).
    progress : None, True (a stderr line per segment) or a callable ``(message, done=False)``.

    Returns
    -------
    :class:`OracleResult` (``actions`` (E, M, k), ``log`` of the chosen path).

    Not guaranteed to beat the best constant action: each choice is greedy over segment + lookahead.
    """
    return _search(env_id, env_kwargs, seeds, grid, segment_s, lookahead_s, "oracle-schedule", batch_rows,
                   progress)[0]


def best_per_episode(env_id: str, env_kwargs: dict | None, seeds, grid=DEFAULT_GRID_N,
                     batch_rows: int = BATCH_ROWS, progress=None) -> OracleResult:
    """The best constant action of each episode in hindsight (lowest squared horizontal error of the episode).

    Cost: K episode-equivalents per episode. Parameters as :func:`greedy_schedule`;
    ``details['branch_cost_m2']`` (E, 1, K) holds every candidate's sum of squared errors.
    """
    return _search(env_id, env_kwargs, seeds, grid, None, None, "best-per-episode", batch_rows, progress,
                   whole_episode=True)[0]


def crossfit_schedule(env_id: str, env_kwargs: dict | None, seeds, segment_s: float = 10.0,
                      lookahead_s: float = 20.0, grid=DEFAULT_GRID_N, progress=None) -> OracleResult:
    """One time-indexed schedule (an action per segment, shared by all episodes), cross-fitted.

    The episodes are split in two halves (the first ``ceil(E / 2)`` seeds and the rest). On each half one
    shared schedule is fitted greedily (as :func:`greedy_schedule`, but each segment's candidate minimizes
    the squared error summed over all episodes of the half); each episode is then scored by the schedule
    fitted on the *other* half (a replay through the env). This measures what a policy could win by
    memorizing *when* the scenario's events happen, never having seen the episode itself.

    Cost: ``K (segment + lookahead) / segment`` episode-equivalents per episode for the fits, plus one for
    the scoring. A half is fitted in one batch (half the episodes x K rows).

    Returns
    -------
    :class:`OracleResult` whose ``actions`` are the scoring schedules (each half's rows hold the other
    half's fit); ``details['halves']`` the two lists of episode indices, ``details['schedules']`` the
    (M, k) schedule fitted on each half (``'first'``, ``'second'``), ``details['choices']`` its candidate
    index per segment and ``details['fit_branch_cost_m2']`` (E_half, S, K) the branch costs of each fit.
    """
    _, _, _, seeds, _ = _setup(env_id, env_kwargs, seeds, grid)
    if len(seeds) < 2:
        raise ValueError("crossfit_schedule needs at least 2 seeds (two halves)")
    t0 = time.perf_counter()
    h = (len(seeds) + 1) // 2
    halves = (list(range(h)), list(range(h, len(seeds))))
    fits = {}
    for name, idx in zip(("first", "second"), halves):
        res, env_kwargs = _search(env_id, env_kwargs, [seeds[i] for i in idx], grid, segment_s, lookahead_s,
                                  f"crossfit-schedule (fit on the {name} half)", BATCH_ROWS, progress, pooled=True)
        fits[name] = res
    sched = {name: r.actions[0] for name, r in fits.items()}  # all rows of a pooled fit share the schedule
    actions = np.empty((len(seeds),) + sched["first"].shape)
    actions[halves[0]] = sched["second"]
    actions[halves[1]] = sched["first"]
    log = run_policy_episodes(env_id, env_kwargs, ScheduledPolicy(actions), seeds)
    wall = time.perf_counter() - t0
    log = EpisodeLog(**{**{f: getattr(log, f) for f in EpisodeLog.__dataclass_fields__}, "filter_time_s": wall})
    E = len(seeds)
    eq = sum(r.details["episode_equivalents"] * len(r.seeds) for r in fits.values()) / E + 1.0
    f0 = fits["first"].details
    details = {"segment_epochs": f0["segment_epochs"], "lookahead_epochs": f0["lookahead_epochs"],
               "halves": [list(halves[0]), list(halves[1])], "schedules": sched,
               "choices": {name: r.details["choices"][0] for name, r in fits.items()},
               "fit_branch_cost_m2": {name: r.details["branch_cost_m2"] for name, r in fits.items()},
               "episode_equivalents": eq, "wall_time_s": wall}
    return OracleResult("crossfit-schedule", env_id, seeds, fits["first"].grid, actions, log, details)
