"""The contract of the registered adaptive laws: they never lose badly against ``kf``.

On paired episodes (episode k of every method sees the same world; eval.py's episode seeds), every law of
:data:`nav_filters.registry.ADAPTIVE_METHODS`

* is within 5 % of ``kf``'s pooled horizontal RMSE on the clean-sky scenarios (``open-sky``, and
  ``low-noise``, where the innovations sit far below what the filter predicts and the Sage-Husa Q law used to
  drift: 1.97x ``kf`` before the fix, on these episodes);
* has no single episode worse than twice ``kf``'s horizontal RMSE on the urban-like scenarios
  (:data:`envs.sim.scenarios.URBAN_LIKE`: NLOS / multipath biases on some satellites).

32 episodes of 240 s per scenario (the Q drift shows after ~150 s), seed 3: a seed none of the laws' choices
were measured on (their docstrings quote seeds 1, 2, 4 and development seeds). The misses measured on these
episodes are marked ``xfail(strict=True)`` with their figures, so the day a law meets the contract the mark has
to go.
"""
from __future__ import annotations

import numpy as np
import pytest

from envs.episodes import run_episodes
from experiments import episode_seeds
from envs.sim.scenarios import URBAN_LIKE
from envs.worlds import make_world
from nav_filters.registry import ADAPTIVE_METHODS

SEED = 3
EPISODES = 32
DURATION_S = 240.0
CLEAN = ("open-sky", "low-noise")
POOLED_LIMIT = 1.05
EPISODE_LIMIT = 2.0
LAWS = tuple(sorted(ADAPTIVE_METHODS))

_RUNS: dict = {}


def episode_rmse(scenario: str) -> dict:
    """``{method: (E,) horizontal RMSE of each episode [m]}`` of ``kf`` and every law on the scenario's paired
    episodes (computed once per scenario)."""
    if scenario not in _RUNS:
        world = make_world(scenario, episode_seeds(SEED, EPISODES), duration_s=DURATION_S)
        out = {}
        for method in ("kf",) + LAWS:
            log = run_episodes(world, method)
            assert not log.diverged.any(), (scenario, method)
            out[method] = np.sqrt(np.mean(log.horizontal_error ** 2, axis=1))
        _RUNS[scenario] = out
    return _RUNS[scenario]


_UNCHANGED = "a law this work did not change; no fix attempted"
_START_IN_NLOS = ("the episode starts with 3 satellites, all NLOS, for 30 s; the law down-weights one of them, the "
                  "other two pull the weakly observed state elsewhere, and with 2-3 satellites its 65-80 m error "
                  "takes 150 s to close where kf's closes in 10 s (before the median guard and the Q bound: 3.04x)")
_GROUP_R = "one pseudorange scale blames every satellite for an NLOS one (the law before per-satellite R)"
MISSES = {
    ("open-sky", "stkf"): f"1.217 m, 1.061x kf (1.147 m): {_UNCHANGED}",
    ("low-noise", "stkf"): f"0.096 m, 1.055x kf (0.091 m): {_UNCHANGED}",
    ("low-noise", "sage-husa-group"): "0.097 m, 1.061x kf (0.091 m): the group law keeps the printed Q bound (Q may "
                                      "fall below the nominal one); q_lower='nominal' gave 0.97x on 16 development "
                                      "episodes but outage 8.2 -> 14.0 m (kf 8.1) and open-sky 1.02 -> 1.06x kf",
    ("urban", "sage-husa"): f"episode 25: 43.3 m, 2.54x kf (17.0 m): {_START_IN_NLOS}",
    ("urban", "svd-akf"): f"episode 25: 43.3 m, 2.54x kf (17.0 m): {_START_IN_NLOS}",
    ("urban", "svd-asrkf"): f"episode 25: 35.6 m, 2.09x kf (17.0 m): {_START_IN_NLOS}",
    ("urban", "sage-husa-r"): f"episode 25: 43.9 m, 2.58x kf (17.0 m): {_START_IN_NLOS}",
    ("urban", "sage-husa-group"): f"episode 25: 66.7 m, 3.92x kf (17.0 m), 3 episodes over 2x: {_GROUP_R}",
    ("urban-transition", "stkf"): f"episode 3: 9.84 m, 4.13x kf (2.38 m): {_UNCHANGED}",
    ("urban-transition", "ma-stkf"): f"episode 3: 9.24 m, 3.87x kf (2.38 m): {_UNCHANGED}",
    ("regime-switch", "ma-stkf"): f"episode 28: 22.5 m, 2.30x kf (9.77 m): {_UNCHANGED}",
    ("regime-switch", "sage-husa-group"): f"episode 28: 46.0 m, 4.71x kf (9.77 m): {_GROUP_R}",
    ("open-sky", "vb-akf"): "1.228 m, 1.070x kf (1.147 m): the variational-Bayes R law inflates a satellite whose "
                            "slowly varying atmosphere residual persists for minutes (scale 4-6 on a 22 deg "
                            "satellite, measured on a development episode where it costs 2.1x kf); neither its "
                            "floor (scale_min 1, 0.5, 0.25) nor a longer memory (rho 0.98, 0.99: 1.03x on 32 "
                            "development episodes) removes it",
}
"""``(scenario, law): what was measured`` for the misses on these episodes (``xfail(strict=True)``)."""


def _cases(scenarios):
    return [pytest.param(s, law, marks=pytest.mark.xfail(strict=True, reason=MISSES[(s, law)]))
            if (s, law) in MISSES else pytest.param(s, law) for s in scenarios for law in LAWS]


@pytest.mark.slow
@pytest.mark.parametrize("scenario,law", _cases(CLEAN))
def test_pooled_rmse_within_5_percent_of_kf_under_a_clean_sky(scenario, law):
    runs = episode_rmse(scenario)
    pooled = {m: float(np.sqrt(np.mean(e ** 2))) for m, e in runs.items()}
    ratio = pooled[law] / pooled["kf"]
    assert ratio <= POOLED_LIMIT, f"{law} on {scenario}: {pooled[law]:.3f} m, {ratio:.3f}x kf ({pooled['kf']:.3f} m)"


@pytest.mark.slow
@pytest.mark.parametrize("scenario,law", _cases(URBAN_LIKE))
def test_no_episode_worse_than_twice_kf_in_urban_like_scenarios(scenario, law):
    runs = episode_rmse(scenario)
    ratio = runs[law] / runs["kf"]
    k = int(np.argmax(ratio))
    assert ratio[k] <= EPISODE_LIMIT, (f"{law} on {scenario}: episode {k} {runs[law][k]:.2f} m, {ratio[k]:.2f}x kf "
                                       f"({runs['kf'][k]:.2f} m); {int((ratio > EPISODE_LIMIT).sum())} episodes "
                                       f"over {EPISODE_LIMIT}x")
