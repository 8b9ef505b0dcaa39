"""Policies that drive the tuning environments: ``act(obs) -> action`` for a batch of observations.

* :class:`ConstantPolicy` -- a fixed action (a fixed filter parameter, e.g. Sage-Husa ``b = 0.98``).
* :class:`ReactiveRule` -- a hand-designed causal rule: a short memory of the noise (small ``b``) while the
  satellites' normalized innovations are high, a long one otherwise (seed 000 eq 24's lowering of b).
* :class:`ScheduledPolicy` -- a fixed action per episode and epoch (the replay of an oracle's schedule).
* :class:`Sb3Policy` -- a trained stable-baselines3 / sb3-contrib model (``model.zip``, or a run's ``best/`` or
  ``checkpoints/`` model), with the observation statistics saved with it when training used them
  (``vecnormalize.pkl``; a model trained on normalized observations without them is an error), and recurrent
  state for ``RecurrentPPO``.
"""
from __future__ import annotations

import json
import pickle
import re
from pathlib import Path

import numpy as np

ALGOS = ("ppo", "sac", "td3", "recurrentppo")


def algo_class(algo: str):
    """The SB3 / sb3-contrib class of ``algo`` (``ValueError`` for an unknown name)."""
    algo = algo.lower()
    if algo == "ppo":
        from stable_baselines3 import PPO
        return PPO
    if algo == "sac":
        from stable_baselines3 import SAC
        return SAC
    if algo == "td3":
        from stable_baselines3 import TD3
        return TD3
    if algo == "recurrentppo":
        from sb3_contrib import RecurrentPPO
        return RecurrentPPO
    raise ValueError(f"unknown algorithm {algo!r}; known: {', '.join(ALGOS)}")


class ConstantPolicy:
    """Always the same action (B, k) for any observation batch."""

    def __init__(self, action):
        self.action = np.atleast_1d(np.asarray(action, np.float32))

    def reset(self, batch_size: int):
        pass

    def act(self, obs):
        return np.broadcast_to(self.action, (obs.shape[0], self.action.size)).copy()


class ScheduledPolicy:
    """A fixed per-epoch action schedule: the j-th ``act`` call after ``reset`` returns ``actions[:, j]``.

    Replays what :mod:`agents.oracles` found through the env core (``run_policy_episodes``): the float64
    actions are handed over unchanged, so a replay reproduces the oracle's errors bit for bit.

    Parameters
    ----------
    actions : (B, M, k) actions in [-1, 1] of B episodes at each of their M epochs.
    """

    def __init__(self, actions):
        a = np.array(actions, np.float64)
        if a.ndim != 3 or 0 in a.shape:
            raise ValueError(f"actions must have shape (B, M, k) with B, M, k >= 1, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("actions contains NaN or inf")
        self.actions = a
        self._j = 0

    def reset(self, batch_size: int):
        if batch_size != self.actions.shape[0]:
            raise ValueError(f"the schedule has {self.actions.shape[0]} episodes, the batch {batch_size}")
        self._j = 0

    def act(self, obs):
        B, M, _ = self.actions.shape
        if np.shape(obs)[0] != B:
            raise ValueError(f"the schedule has {B} episodes, the observation batch {np.shape(obs)[0]}")
        if self._j >= M:
            raise ValueError(f"the schedule has {M} epochs; act() was called a {self._j + 1}th time since reset()")
        a = self.actions[:, self._j].copy()
        self._j += 1
        return a


class ReactiveRule:
    """Hand-designed causal rule for the Sage-Husa env: ``b = b_low`` while the satellites look degraded,
    ``b_high`` otherwise, with a hold time.

    Degraded: the largest per-satellite pseudorange normalized innovation (observation ``nis_pr_sat_max``)
    above ``nis``, or the pseudorange NIS moving average (``nis_pr_ema``) above ``ema``; the low b is held for
    ``hold`` epochs after the last degraded epoch. Seed 000 eq 24 lowers b when the Q correction jumps;
    this rule lowers it when the measurements do, from the observation only (no truth).

    Parameters
    ----------
    specs : the env's parameter specs (the first must be ``b``); k : the number of action components.
    frame_dim : length of one observation frame (the newest frame is the last one).
    b_low, b_high : forgetting factors in the env's range; nis, ema : thresholds; hold : epochs (>= 0).
    """

    def __init__(self, specs, frame_dim: int, b_low: float = 0.5, b_high: float = 0.9999, nis: float = 9.0,
                 ema: float = 3.0, hold: int = 5):
        from envs.core import OBS_FEATURES
        names = [f[0] for f in OBS_FEATURES]
        if not specs or specs[0].name != "b":
            raise ValueError("ReactiveRule drives a Sage-Husa forgetting factor b (GnssIns/SageHusa-v1)")
        for name, v in (("b_low", b_low), ("b_high", b_high)):
            if not specs[0].low <= v <= specs[0].high:
                raise ValueError(f"{name} must lie in [{specs[0].low}, {specs[0].high}], got {v!r}")
        if not (nis > 0 and ema > 0 and int(hold) == hold and hold >= 0):
            raise ValueError(f"nis and ema must be > 0 and hold an int >= 0, got {nis!r}, {ema!r}, {hold!r}")
        self.k, self.frame_dim = len(specs), int(frame_dim)
        self.i_max = self.k + names.index("nis_pr_sat_max")
        self.i_ema = self.k + names.index("nis_pr_ema")
        self.a_low = float(specs[0].to_action(b_low))
        self.a_high = float(specs[0].to_action(b_high))
        self.nis, self.ema, self.hold = float(nis), float(ema), int(hold)
        self.rest = np.array([s.to_action(s.default) for s in specs[1:]], np.float32)
        self._left = None

    def reset(self, batch_size: int):
        self._left = np.zeros(batch_size, np.int64)

    def act(self, obs):
        f = np.asarray(obs)[:, -self.frame_dim:]
        bad = (f[:, self.i_max] > self.nis) | (f[:, self.i_ema] > self.ema)
        self._left = np.where(bad, self.hold + 1, np.maximum(self._left - 1, 0))
        a = np.where(self._left > 0, self.a_low, self.a_high).astype(np.float32)[:, None]
        if self.rest.size:
            a = np.concatenate([a, np.broadcast_to(self.rest, (a.shape[0], self.rest.size))], 1)
        return a


def _run_files(path: Path) -> tuple[Path, Path]:
    """``(config.json, observation statistics)`` of the model file ``path`` of a ``train.py rl`` run (either may
    not exist): beside the model (the run's ``model.zip`` and ``vecnormalize.pkl``), or, for a model in the run's
    ``best/`` or ``checkpoints/``, the run's ``config.json`` one folder up and the statistics saved with that
    model (``best/vecnormalize.pkl``; SB3's ``<prefix>_vecnormalize_<steps>_steps.pkl`` beside
    ``<prefix>_<steps>_steps.zip``)."""
    here = path.parent
    cfg = here / "config.json"
    if not cfg.is_file() and here.name in ("best", "checkpoints"):
        cfg = here.parent / "config.json"
    vn = here / "vecnormalize.pkl"
    m = re.fullmatch(r"(.+)_(\d+)_steps\.zip", path.name)
    if not vn.is_file() and m:
        vn = here / f"{m.group(1)}_vecnormalize_{m.group(2)}_steps.pkl"
    return cfg, vn


def _read_config(path: Path) -> dict:
    """``config.json`` beside a model as a dict ({} when absent); ``ValueError`` naming it when unreadable."""
    if not path.is_file():
        return {}
    try:
        c = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: not a JSON file ({e})") from None
    if not isinstance(c, dict) or not isinstance(c.get("env_kwargs", {}), dict):
        raise ValueError(f"{path}: expected a JSON object with 'env' and a mapping 'env_kwargs'")
    return c


def _policy_hint(path: Path) -> str:
    """'; it holds a <PolicyClass> (<module>)' from the zip's saved data, or '' when that cannot be read."""
    import zipfile
    try:
        with zipfile.ZipFile(path) as z:
            pc = json.loads(z.read("data"))["policy_class"]
        name = str(pc["__init__"]).split()[1].split(".")[0]
        return f"; it holds a {name} ({pc['__module__']})"
    except Exception:  # noqa: BLE001  (a hint only)
        return ""


class Sb3Policy:
    """A trained model: ``Sb3Policy.load("runs/x/model.zip", algo="ppo")``.

    ``config.json`` beside the model (written by ``train.py rl``) gives the env id and env kwargs the policy
    was trained on (:attr:`env_id`, :attr:`env_kwargs`).
    """

    def __init__(self, model, algo: str, obs_rms=None, clip_obs: float = 10.0, epsilon: float = 1e-8,
                 env_id: str | None = None, env_kwargs: dict | None = None):
        self.model, self.algo = model, algo
        self.obs_rms, self.clip_obs, self.epsilon = obs_rms, clip_obs, epsilon
        self.env_id, self.env_kwargs = env_id, dict(env_kwargs or {})
        self._state = None
        self._start = None

    @classmethod
    def load(cls, path, algo: str):
        """Load ``path`` (a ``model.zip``) as an ``algo`` model, with its observation statistics and its run's
        ``config.json`` when present (:func:`_run_files`: beside it, or for a ``best/`` or ``checkpoints/`` model of
        a ``train.py rl`` run, those saved with it and the run's).

        Raises
        ------
        FileNotFoundError
            no such model file.
        ValueError
            a file that cannot be used, named with the reason: a damaged or foreign ``model.zip``, a model of
            another algorithm (``config.json``'s ``algo`` or the saved policy class), an unreadable
            ``vecnormalize.pkl`` or one whose statistics do not fit the model's observations, a
            ``config.json`` that is not a JSON object, a model trained on normalized observations (its run's
            ``config.json``: ``normalize``) whose statistics are missing.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"model file not found: {path}")
        algo = algo.lower()
        klass = algo_class(algo)
        cfg_file, vn = _run_files(path)
        cfg = _read_config(cfg_file)
        saved = cfg.get("algo")
        if saved is not None and str(saved).lower() != algo:
            raise ValueError(f"{path}: trained with {saved!r} ({cfg_file}), given as {algo!r}; "
                             f"use '{str(saved).lower()}:{path}'")
        try:
            model = klass.load(str(path), device="cpu")
        except Exception as e:  # noqa: BLE001  (a damaged or foreign zip: SB3 raises anything, from BadZipFile to AttributeError)
            raise ValueError(f"{path}: cannot load it as a {algo} model{_policy_hint(path)} "
                             f"({type(e).__name__}: {str(e).strip().splitlines()[0] if str(e).strip() else ''})") from None
        policies = tuple(getattr(klass, "policy_aliases", {}).values())
        if policies and not isinstance(model.policy, policies):
            raise ValueError(f"{path}: holds a {type(model.policy).__name__}, not a {algo} policy "
                             f"({', '.join(p.__name__ for p in policies)})")
        obs_rms, clip, eps = None, 10.0, 1e-8
        if not vn.is_file() and cfg.get("normalize"):
            raise ValueError(f"{path}: trained on normalized observations ({cfg_file}: normalize true) but their "
                             f"statistics are not there ({vn}); without them the policy would see raw observations. "
                             f"Evaluate the run's model.zip, or a best/ or checkpoints/ model saved with its "
                             f"statistics")
        if vn.is_file():
            try:
                with open(vn, "rb") as f:
                    venv = pickle.load(f)
            except Exception as e:  # noqa: BLE001  (unpickling garbage raises anything)
                raise ValueError(f"{vn}: not a VecNormalize file ({type(e).__name__}: {e})") from None
            if getattr(venv, "norm_obs", False):
                obs_rms, clip, eps = getattr(venv, "obs_rms", None), getattr(venv, "clip_obs", None), \
                    getattr(venv, "epsilon", None)
                shape = model.observation_space.shape
                if (np.shape(getattr(obs_rms, "mean", None)) != shape or np.shape(getattr(obs_rms, "var", None)) != shape
                        or not isinstance(clip, (int, float)) or not isinstance(eps, (int, float))):
                    raise ValueError(f"{vn}: its observation statistics do not fit the model's observations {shape}")
        return cls(model, algo, obs_rms, clip, eps, cfg.get("env"), cfg.get("env_kwargs") or {})

    def reset(self, batch_size: int):
        self._state = None
        self._start = np.ones(batch_size, bool)

    def _normalize(self, obs):
        if self.obs_rms is None:
            return obs
        return np.clip((obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + self.epsilon),
                       -self.clip_obs, self.clip_obs).astype(np.float32)

    def _fit_channels(self, n_obs: int) -> None:
        """A per-satellite policy given observations of another channel count than it was trained on (a recording's
        receiver has its own): its set policy is rebuilt for that count with the same weights
        (:func:`agents.set_policy.with_channels`); any other size mismatch is a ``ValueError`` naming both sizes."""
        have = int(self.model.observation_space.shape[0])
        if n_obs == have:
            return
        from envs.satellite_env import channel_layout

        from .set_policy import CHANNEL_SET_POLICIES, with_channels
        if not isinstance(self.model.policy, CHANNEL_SET_POLICIES) or self.obs_rms is not None:
            raise ValueError(f"the policy observes {have} values, the env gives {n_obs}")
        lay = channel_layout(self.model.observation_space)
        channels, rest = divmod(n_obs - lay.global_dim, lay.features + 1)
        if rest or channels < 1:
            raise ValueError(f"the policy observes {have} values, the env gives {n_obs}: not a channel count of "
                             f"its layout ({lay.global_dim} + C x {lay.features + 1})")
        pol = with_channels(self.model.policy, channels)
        self.model.policy, self.model.observation_space, self.model.action_space = \
            pol, pol.observation_space, pol.action_space

    def act(self, obs):
        """(B, k) deterministic actions for the observations (B, obs_dim), one row at a time.

        Row by row, so that a row's action does not depend on the batch it is evaluated in: torch's float32
        matrix products pick their kernels (blocking, vectorization) by the batch size, and a batched forward
        pass changed the first layer's outputs by up to 6e-7 between B = 64 and B = 1 (measured on an MLP
        policy), which made ``eval.py --batch-size 1`` and ``--batch-size 64`` differ in the last digits.
        The recurrent state is kept and sliced per row."""
        obs = np.asarray(obs, np.float32)
        self._fit_channels(obs.shape[-1])
        o = self._normalize(obs)
        B = o.shape[0]
        if self.algo == "recurrentppo":
            acts, states = [], []
            for i in range(B):
                st = None if self._state is None else tuple(s[:, i:i + 1] for s in self._state)
                a, st = self.model.predict(o[i:i + 1], state=st, episode_start=self._start[i:i + 1],
                                           deterministic=True)
                acts.append(a)
                states.append(st)
            self._state = tuple(np.concatenate([st[k] for st in states], axis=1) for k in range(len(states[0])))
            self._start = np.zeros(B, bool)
        else:
            acts = [self.model.predict(o[i:i + 1], deterministic=True)[0] for i in range(B)]
        return np.concatenate([np.asarray(a, np.float32).reshape(1, -1) for a in acts], 0)
