"""Reproductions of the seed papers' comparisons in our simulation (issue 3), paper figures beside ours.

``run_experiment(name, episodes=None, seed=0, out_dir=None, progress=None)``
runs one experiment of :data:`EXPERIMENTS` and returns ``(results, report)``:
a JSON-ready dict and a Markdown report that prints **our** figures (always
computed by running the code) beside **the paper's** figures (typed from the
paper tables as the constants below, each naming its table), plus one verdict
per claim: ``reproduced`` or ``not reproduced``, and, for the latter, why (from
the measured diagnostics, never assumed beforehand).

=========  ===================================================================================
name       what
=========  ===================================================================================
seed000    seed paper 000: kf / svd-srkf / svd-kf / svd-asrkf / svd-akf / if / svd-if in
           float32 filter arithmetic on ``seed000-sim`` with a fluctuating GNSS quality (true
           code/Doppler noise bursts, :data:`SEED000_EVENTS`); RMSE per axis (ENU and ECEF) and
           max error; plus kf in float64 as the rounding-free reference; and the max-error claim
           of the dynamic (city-drive) experiment rerun on ``urban-transition``, its setting.
seed001    seed paper 001: per-sample vs one-step (``+onestep``) prediction of P for kf and
           svd-kf on ``seed000-sim``, ``open-sky`` and ``outage``: filter time and accuracy
           degradation (RMSE, max, drift during outages).
seed003    seed paper 003: kf vs stkf vs ma-stkf on ``seed003-sim``: RMSE and MAD of the
           latitude / longitude error [m] and the east / north velocity error [m/s], with the
           paper's sensor set (GNSS + odometer + NHC, :data:`SEED003_ODOMETER`) and GNSS only.
=========  ===================================================================================

Episodes are paired (episode k of every method sees the same truth and sensor
errors; seeds as in ``eval.py``: ``seed * 1_000_003 + k``). Paired differences
carry a percentile-bootstrap 95% CI over episodes. Verdicts (:func:`verdict`):
a relative change claimed by the paper is ``reproduced`` when our CI lies
entirely on the paper's side of zero and our change is at least half the
paper's, ``direction only`` when the CI is on the paper's side but the change is
smaller, ``not reproduced`` otherwise; a bound ("degradation below 2%") is
reproduced when the upper end of our CI is below it; a time saving when ours is
at least the paper's minus 10 points. Below :data:`envs.metrics.MIN_CI_EPISODES`
episodes behind a claim (paired episodes without a divergence; all episodes for
a time claim) there is no verdict and no CI, as in eval.py's tables: the claim's
``verdict`` and ``ci95`` are null, its ``why`` and the report's verdict column
say :func:`envs.metrics.no_ci_text` (:func:`make_claim`), and seed001's
degradation CIs are null too.

``results`` layout (every experiment)::

    {"experiment": name, "episodes": E, "seed": s, "episode_seeds": [...], "wall_time_s": t,
     "setup": {...}, "ours": {...}, "paper": {...},
     "claims": [{"id", "claim", "source", "paper", "ours", "ci95", "verdict", "why", "episodes"}, ...]}

``ours`` per experiment: see :func:`run_seed000`, :func:`run_seed001`, :func:`run_seed003`.
With ``out_dir`` the results and report are also written to
``out_dir/<name>.json`` and ``out_dir/<name>.md``.

Two runs here need what :func:`envs.episodes.run_episodes` has no hook for (a
predict at every IMU sample, the "standard algorithm" of seed 001; odometer/NHC
rows fused at every epoch, seed 003's sensor set): :func:`run_navigation` is
the same loop with those two options (with neither it reproduces
``run_episodes`` exactly; tested).

Modules: :mod:`.papers` (the papers' figures and the setups), :mod:`.navigation` (paired episodes, runs,
:func:`run_navigation`), :mod:`.claims` (paired changes, verdicts, claims, Markdown), :mod:`.seed000`,
:mod:`.seed001`, :mod:`.seed003` (one experiment each) and :mod:`.runner` (:func:`run_experiment`). The
package sits on top of the env core (it imports :mod:`envs` and :mod:`nav_filters`; nothing in the env
core imports it).
"""
from __future__ import annotations

from envs.sim.odometer import SEED003_ODOMETER, OdometerModel
from .claims import (N_BOOT, VERDICTS, _ci_pct, _claims_table, make_claim, paired_change,  # noqa: F401
                     verdict, verdict_summary)
from .navigation import Run, episode_seeds, run_navigation, simulate_odometer
from .papers import *  # noqa: F401,F403  (the papers' figures and the setups: SEED000_TABLE2_RMSE_M, ...)
from .runner import DEFAULT_EPISODES, EXPERIMENTS, run_experiment
from .seed000 import run_seed000
from .seed001 import run_seed001
from .seed003 import run_seed003

__all__ = ["EXPERIMENTS", "DEFAULT_EPISODES", "run_experiment", "run_seed000", "run_seed001", "run_seed003",
           "run_navigation", "simulate_odometer", "paired_change", "verdict", "make_claim", "verdict_summary",
           "episode_seeds", "Run", "OdometerModel", "VERDICTS",
           "SEED000_TABLE2_RMSE_M", "SEED000_MAX_ERROR_M", "SEED000_EVENTS", "SEED001_TABLE6_TIME_S",
           "SEED003_TABLE2", "SEED003_ODOMETER"]
