"""Stable-Baselines3 adapter: a native vector env seen through SB3's ``VecEnv`` API.

SB3 auto-resets finished rows in the same step, puts the last observation in
``infos[i]["terminal_observation"]`` and flags time-limit ends with
``infos[i]["TimeLimit.truncated"]``; the native env already resets in the same
step (``SAME_STEP``), so the adapter only reshapes its outputs.

Usage::

    from envs.sb3 import make_sb3_vec_env
    venv = make_sb3_vec_env("GnssIns/SageHusa-v1", n_envs=16, seed=0, episode_length_s=60.0)
    model = stable_baselines3.PPO("MlpPolicy", venv)
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv


class Sb3VecEnvAdapter(VecEnv):
    """Wrap a :class:`envs.vector_env.GnssInsTuningVectorEnv` as an SB3 ``VecEnv``."""

    def __init__(self, venv):
        self.venv = venv
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions = None
        self._seed = None

    def reset(self):
        obs, _ = self.venv.reset(seed=self._seed)
        self._seed = None
        return obs

    def seed(self, seed=None):
        self._seed = seed
        return [None if seed is None else seed + i for i in range(self.num_envs)]

    def step_async(self, actions):
        self._actions = np.asarray(actions)

    def step_wait(self):
        obs, rew, term, trunc, info = self.venv.step(self._actions)
        done = term | trunc
        keys = [k for k in info if not k.startswith("_") and k not in ("final_obs", "final_info")]
        # one conversion per info array (Python scalars, as .item() gives), then one dict per row
        cols = [v.tolist() if isinstance(v, np.ndarray) and v.dtype != object else [v[i] for i in range(self.num_envs)]
                for v in (info[k] for k in keys)]
        infos = [dict(zip(keys, vals)) for vals in zip(*cols)] if keys else [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(done):
            d = infos[i]
            d["terminal_observation"] = info["final_obs"][i]
            d["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
            d["episode_metrics"] = info["final_info"][i]["episode_metrics"]
        return obs, rew.astype(np.float32), done, infos

    def close(self):
        self.venv.close()

    def get_attr(self, attr_name, indices=None):
        return [getattr(self.venv, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name, value, indices=None):
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name, *args, indices=None, **kwargs):
        return [getattr(self.venv, method_name)(*args, **kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False for _ in self._get_indices(indices)]

    def _get_indices(self, indices):
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else indices


def make_sb3_vec_env(env_id: str, n_envs: int, seed: int | None = None, **kwargs) -> Sb3VecEnvAdapter:
    """The native vector env of ``env_id`` (``gym.make_vec(..., vectorization_mode="vector_entry_point")``)
    behind the SB3 adapter; ``seed`` seeds row i with ``seed + i`` at the first reset."""
    venv = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", **kwargs)
    ad = Sb3VecEnvAdapter(venv.unwrapped if hasattr(venv, "unwrapped") else venv)
    if seed is not None:
        ad.seed(seed)
    return ad
