"""Native batched vector environments: B episodes in one batched navigator (gymnasium 1.x ``VectorEnv``).

Autoreset mode: ``SAME_STEP`` (stated in ``metadata["autoreset_mode"]``). When a
row's episode ends, ``step`` returns the *first observation of its next
episode* in ``obs`` and the last one in ``info["final_obs"]`` (masked by
``info["_final_obs"]``), with ``info["final_info"]`` holding the finished
episode's metrics. Seeding: ``reset(seed=s)`` seeds row i with ``s + i`` (an
int list seeds rows individually), so row i equals the single env reset with
``seed=s + i``, also across automatic resets.
"""
from __future__ import annotations

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .core import TuningCore, check_batch_size, draw_world_seed
from .gnss_ins_env import MASTKF_PARAMS, SAGE_HUSA_PARAMS, STKF_PARAMS, make_config


class GnssInsTuningVectorEnv(VectorEnv):
    """Vector version of :class:`envs.gnss_ins_env.GnssInsTuningEnv` (same arguments plus ``num_envs``)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
    PARAMS = SAGE_HUSA_PARAMS
    DEFAULTS = {"method": "sage-husa"}

    def __init__(self, num_envs: int = 1, **kwargs):
        kwargs.pop("render_mode", None)
        self.num_envs = check_batch_size(num_envs, "num_envs")
        self.config = make_config(self.DEFAULTS, kwargs)
        self.core = TuningCore(self.config, self.PARAMS, self.num_envs)
        k = self.core.k
        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(k,), dtype=np.float32)
        self.single_observation_space = spaces.Box(self.core.obs_low, self.core.obs_high, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs = [None] * self.num_envs

    def _next_seeds(self, rows):
        return [draw_world_seed(self._rngs[i]) for i in rows]

    def reset(self, *, seed=None, options=None):
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed list must have {self.num_envs} entries, got {len(seeds)}")
        self._rngs = [seeding.np_random(s)[0] for s in seeds]
        rows = np.arange(self.num_envs)
        world_seeds = self._next_seeds(rows)
        obs = self.core.reset_rows(rows, world_seeds)
        return obs, {"seed": np.array(world_seeds), "_seed": np.ones(self.num_envs, bool)}

    def step(self, actions):
        res = self.core.step(actions)
        infos = dict(res.info)
        for key in list(infos):
            infos["_" + key] = np.ones(self.num_envs, bool)
        done = res.terminated | res.truncated
        obs = res.obs
        if done.any():
            rows = np.flatnonzero(done)
            final_obs = np.empty(self.num_envs, dtype=object)
            final_info = np.empty(self.num_envs, dtype=object)
            metrics = self.core.episode_metrics(rows)
            for r, m in zip(rows, metrics):
                final_obs[r] = obs[r].copy()
                final_info[r] = {"episode_metrics": m}
            infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
            infos["final_info"], infos["_final_info"] = final_info, done.copy()
            obs = obs.copy()
            obs[rows] = self.core.reset_rows(rows, self._next_seeds(rows))
        return obs, res.reward.astype(np.float64), res.terminated.copy(), res.truncated.copy(), infos


class SageHusaVectorEnv(GnssInsTuningVectorEnv):
    """Vector ``GnssIns/SageHusa-v0``."""

    PARAMS = SAGE_HUSA_PARAMS
    DEFAULTS = {"method": "sage-husa"}


class StkfVectorEnv(GnssInsTuningVectorEnv):
    """Vector ``GnssIns/STKF-v0``."""

    PARAMS = STKF_PARAMS
    DEFAULTS = {"method": "stkf"}


class MaStkfVectorEnv(GnssInsTuningVectorEnv):
    """Vector ``GnssIns/MASTKF-v0``."""

    PARAMS = MASTKF_PARAMS
    DEFAULTS = {"method": "ma-stkf"}
