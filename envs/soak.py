"""Soak runs of the tuning environments: many randomized row-steps checked for the reliability contract.

The contract (issue 13): no exception escapes a step; observations, rewards and the numeric infos (also
the final observation of an ended episode) are finite; every live row's covariance is positive definite,
or the row was flagged (terminated with ``info["diverged"]`` and a reason) and its episode ended.

:func:`soak` runs one configuration (env id, dtype, scenario, action pattern) through the native vector env
with automatic resets and counts what it saw in a :class:`SoakCounts`; ``tests/envs/test_reliability.py``
asserts the counts on a small grid and ``benchmarks/soak.py`` prints them for a larger one.
"""
from __future__ import annotations

import traceback
from collections import Counter
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np

from nav_filters.navigator import covariance_is_pd

ACTION_PATTERNS = ("bang-bang", "uniform")
"""``'bang-bang'``: every action component -1 and +1 on alternate steps (all rows alike); ``'uniform'``:
independent uniform draws in [-1, 1] per row, component and step."""


@dataclass
class SoakCounts:
    """What a soak run saw.

    Attributes
    ----------
    row_steps : rows x steps stepped.
    exceptions : exceptions that escaped ``reset`` or ``step`` (the run stops at the first).
    nonfinite : row-steps with a NaN or inf in the observation, the reward, a numeric info or a final
        observation.
    non_pd : row-steps after which a live (not flagged) row held a covariance that is not positive definite
        (:func:`nav_filters.navigator.covariance_is_pd`).
    flagged : row-steps that ended an episode as diverged (``info["diverged"]``).
    unexplained : flagged row-steps without a reason in ``info["diverged_reason"]``.
    reasons : flagged row-steps per reason.
    errors : the first lines of the exceptions (with the configuration).
    """

    row_steps: int = 0
    exceptions: int = 0
    nonfinite: int = 0
    non_pd: int = 0
    flagged: int = 0
    unexplained: int = 0
    reasons: Counter = field(default_factory=Counter)
    errors: list = field(default_factory=list)

    def __iadd__(self, other: "SoakCounts") -> "SoakCounts":
        for f in ("row_steps", "exceptions", "nonfinite", "non_pd", "flagged", "unexplained"):
            setattr(self, f, getattr(self, f) + getattr(other, f))
        self.reasons.update(other.reasons)
        self.errors.extend(other.errors)
        return self


def _nonfinite_rows(obs, reward, info, B) -> np.ndarray:
    """(B,) bool: rows with a non-finite value in the step's outputs."""
    bad = ~np.isfinite(obs).all(1) | ~np.isfinite(reward)
    for key, v in info.items():
        if key.startswith("_") or key == "final_info":
            continue
        if key == "final_obs":
            ended = info["_final_obs"]
            bad |= ended & np.array([not (o is None or np.isfinite(np.asarray(o, float)).all()) for o in v])
            continue
        a = np.asarray(v)
        if a.dtype.kind in "fc" and a.shape[:1] == (B,):
            bad |= ~np.isfinite(a.reshape(B, -1)).all(1)
    return bad


def soak(env_id: str, *, scenario: str, dtype: str, actions: str, num_envs: int = 8, steps: int = 60,
         seed: int = 0, **env_kwargs) -> SoakCounts:
    """Step the native vector env of ``env_id`` ``steps`` times and count what the contract forbids.

    Parameters
    ----------
    env_id : a registered id (:data:`envs.ENV_IDS`).
    scenario, dtype : environment arguments; ``env_kwargs`` adds others (e.g. ``episode_length_s``,
        ``imu_grade``).
    actions : one of :data:`ACTION_PATTERNS`.
    num_envs : rows B; steps : vector steps (episodes that end are reset automatically).
    seed : ``reset(seed=...)`` and the uniform action draws.
    """
    if actions not in ACTION_PATTERNS:
        raise ValueError(f"actions must be one of {ACTION_PATTERNS}, got {actions!r}")
    counts = SoakCounts()
    rng = np.random.default_rng(seed)
    where = f"{env_id} {scenario} {dtype} {actions} seed {seed}"
    try:
        env = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", scenario=scenario,
                           dtype=dtype, **env_kwargs)
        env.reset(seed=seed)
        core = env.unwrapped.core
        k = env.single_action_space.shape[0]
        for t in range(steps):
            if actions == "bang-bang":
                a = np.full((num_envs, k), 1.0 if t % 2 else -1.0, np.float32)
            else:
                a = rng.uniform(-1.0, 1.0, (num_envs, k)).astype(np.float32)
            obs, reward, term, trunc, info = env.step(a)
            counts.row_steps += num_envs
            counts.nonfinite += int(_nonfinite_rows(obs, reward, info, num_envs).sum())
            live = ~core.nav.diverged  # ended rows were reset in the same step: live again
            counts.non_pd += int((live & ~covariance_is_pd(core.nav.covariance)).sum())
            div = np.asarray(info["diverged"], bool)
            counts.flagged += int(div.sum())
            reasons = np.asarray(info["diverged_reason"])[div]
            counts.unexplained += int(sum(1 for r in reasons if not r))
            counts.reasons.update(str(r) for r in reasons if r)
        env.close()
    except Exception as e:  # noqa: BLE001  (counting escaped exceptions is the point)
        counts.exceptions += 1
        last = traceback.format_exception_only(type(e), e)[-1].strip()
        counts.errors.append(f"{where}: {last}")
    return counts
