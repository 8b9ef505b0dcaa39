"""Run a policy on B paired episodes through the batched env core (the same worlds as eval.py's filters)."""
from __future__ import annotations

import time
from dataclasses import replace

import gymnasium as gym
import numpy as np

import envs  # noqa: F401  (registers the ids)
from envs.core import TuningCore
from envs.episodes import EpisodeLog


def env_class(env_id: str):
    """The single-env class registered under ``env_id`` (``ValueError`` for an unknown id; a ``FutureWarning``
    naming the current id for an out-of-date one, :func:`envs.warn_if_outdated`)."""
    if env_id not in gym.registry:
        raise ValueError(f"unknown environment id {env_id!r}; known: {sorted(envs.ENV_IDS)}")
    envs.warn_if_outdated(env_id)
    ep = gym.registry[env_id].entry_point
    mod, name = ep.split(":")
    import importlib
    return getattr(importlib.import_module(mod), name)


def run_policy_episodes(env_id: str, env_kwargs: dict, policy, seeds, progress=None) -> EpisodeLog:
    """Run ``policy`` for one full episode on each world seed, all rows in one batched core.

    Parameters
    ----------
    env_id : a registered id (its parameter specs and defaults).
    env_kwargs : :class:`envs.config.EnvConfig` fields (scenario, episode_length_s, method, ...).
    policy : an object with ``reset(B)`` and ``act(obs (B, obs_dim)) -> (B, k)``.
    seeds : the world seeds (the same seeds give the same worlds as ``envs.worlds.make_world``).

    Returns
    -------
    EpisodeLog : positions errors from the core's tracks; NEES and velocity errors are NaN (the env does
    not keep them), ``filter_time_s`` includes the policy's inference, ``params`` the parameter values the
    policy set at each epoch.
    """
    cls = env_class(env_id)
    cfg = cls.config_from(env_kwargs)
    seeds = [int(s) for s in seeds]
    B = len(seeds)
    core = cls.core_for(cfg, B)
    obs = core.reset_rows(np.arange(B), seeds)
    policy.reset(B)
    nis = np.zeros((B, core.M))
    nsat = np.zeros((B, core.M), int)
    zflag = np.zeros((B, core.M), bool)
    diverged = np.zeros(B, bool)
    params = {s.name: np.full((B, core.M), np.nan) for s in cls.PARAMS}
    t0 = time.perf_counter()
    for j in range(core.M):
        res = core.step(policy.act(obs))
        obs = res.obs
        for name, v in params.items():
            v[:, j] = res.info[name]
        nis[:, j] = res.info["nis_pr"]
        nsat[:, j] = res.info["n_sats"]
        zflag[:, j] = res.info["zupt"]
        diverged |= res.terminated
        if progress is not None:
            progress(j + 1)
    elapsed = time.perf_counter() - t0
    log = core_episode_log(core, np.arange(B), nis, nsat, zflag, diverged, elapsed)
    return replace(log, params=params)


def core_episode_log(core: TuningCore, rows, nis, n_sats, zupt, diverged, elapsed_s: float) -> EpisodeLog:
    """The :class:`EpisodeLog` of finished episodes on ``rows`` of ``core`` (position errors from its tracks).

    Parameters
    ----------
    core : a core whose ``rows`` have run all M epochs.
    rows : (E,) int rows of ``core``.
    nis, n_sats, zupt : (E, M) per-epoch pseudorange NIS, satellites used and ZUPT flags of those rows.
    diverged : (E,) bool, terminated at some epoch.
    elapsed_s : wall time to report as ``filter_time_s``.
    """
    rows = np.asarray(rows, np.intp)
    E = rows.size
    err = core.est_track[rows] - core.truth_r[rows]
    ned = (core.truth_Cne[rows] @ err[..., None])[..., 0]
    t = np.asarray(core.epoch_idx, float) * core.dt
    nan = np.full((E, core.M), np.nan)
    return EpisodeLog(t=t, pos_err_ned=ned, vel_err_ned=np.full((E, core.M, 3), np.nan), nees_pv=nan, nis=nis,
                      n_used=n_sats, n_sats=n_sats, gdop=nan.copy(), zupt=zupt,
                      diverged=diverged | ~np.isfinite(ned).all((1, 2)), filter_time_s=elapsed_s)
