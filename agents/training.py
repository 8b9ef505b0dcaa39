"""``train.py rl``: train a tuning policy with stable-baselines3 on the native vector env.

The training loop is SB3's; this module builds what goes around it, explicitly:
the native batched vector env behind the SB3 adapter (:mod:`envs.sb3`), optional
``VecNormalize``, ``VecMonitor`` episode statistics, periodic evaluation on
held-out seeds with the best model kept (``EvalCallback``), checkpoints,
tensorboard + CSV logs, a progress bar, and ``runs/DIR/`` with ``model.zip``,
``vecnormalize.pkl`` (when used) and the exact ``config.json``.

Hyperparameters come from (later wins): the algorithm's defaults in
:data:`DEFAULT_HYPERPARAMS` (on the per-satellite envs with the set policies of :data:`SET_POLICY_HYPERPARAMS`
and observations not normalized, :data:`SATELLITE_NORMALIZE`), the ``--quick`` preset, an RL Zoo style YAML file
(``--config``: ``{env_id: {n_timesteps, policy, n_envs, normalize, env_kwargs, <algo kwargs>}}``),
and the command line (``--timesteps``, ``--n-envs``, ``--env-kwargs``).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from envs.json_io import dumps
from envs.outputs import atomic_path, write_atomic

from .policies import ALGOS, algo_class

EVAL_SEED_OFFSET = 900_000
"""Evaluation during training uses world seeds from here (held out from training and from eval.py)."""

DEFAULT_HYPERPARAMS = {
    "ppo": dict(policy="MlpPolicy", n_steps=128, batch_size=256, n_epochs=10, learning_rate=3e-4, gamma=0.95,
                gae_lambda=0.9, ent_coef=0.0, policy_kwargs=dict(net_arch=[64, 64], optimizer_kwargs=dict(fused=True))),
    "recurrentppo": dict(policy="MlpLstmPolicy", n_steps=128, batch_size=256, n_epochs=10, learning_rate=3e-4,
                         gamma=0.95, gae_lambda=0.9, policy_kwargs=dict(lstm_hidden_size=32, net_arch=[64])),
    "sac": dict(policy="MlpPolicy", learning_rate=3e-4, buffer_size=100_000, batch_size=256, gamma=0.95,
                learning_starts=1000, policy_kwargs=dict(net_arch=[64, 64])),
    "td3": dict(policy="MlpPolicy", learning_rate=3e-4, buffer_size=100_000, batch_size=256, gamma=0.95,
                learning_starts=1000, policy_kwargs=dict(net_arch=[64, 64])),
}
"""Algorithm arguments of ``train.py rl`` (RL Zoo names; ``hyperparams/*.yml`` repeat them). PPO's Adam is
torch's fused implementation (``optimizer_kwargs=dict(fused=True)``): the same update with the same learning
rate, betas and epsilon, one kernel for all parameters instead of ~10 small tensor operations per parameter; it
rounds differently, so a run is not bit for bit the one with the default per-tensor loop."""
SET_POLICY_HYPERPARAMS = {
    "ppo": dict(policy="agents.set_policy.ChannelSetPolicy",
                policy_kwargs=dict(channel_net=[64, 64], context_net=[64], latent_dim=64,
                                   optimizer_kwargs=dict(fused=True))),
    "recurrentppo": dict(policy="agents.set_policy.ChannelSetRecurrentPolicy",
                         policy_kwargs=dict(channel_net=[64, 64], context_net=[64], latent_dim=64,
                                            lstm_hidden_size=32)),
    "sac": dict(policy="agents.set_policy.ChannelSetSACPolicy",
                policy_kwargs=dict(net_arch=[64, 64], channel_net=[64, 64], context_net=[64], latent_dim=64)),
}
"""What replaces :data:`DEFAULT_HYPERPARAMS` on the per-satellite envs (:data:`envs.SATELLITE_ENV_IDS`): the
permutation-equivariant policies of :mod:`agents.set_policy` (TD3 keeps its dense MLP: no set policy for it)."""
SATELLITE_NORMALIZE = dict(norm_obs=False, norm_reward=True)
"""``normalize`` of the per-satellite envs: rewards only (their features are scaled already, and a running
normalization per observation slot would break the channels' symmetry; :mod:`agents.set_policy`)."""


def default_hyperparams(algo: str, env_id: str) -> dict:
    """The algorithm arguments ``train.py rl`` starts from for ``env_id`` (copies)."""
    import envs
    hyper = {k: (dict(v) if isinstance(v, dict) else v) for k, v in DEFAULT_HYPERPARAMS[algo].items()}
    if env_id in envs.SATELLITE_ENV_IDS and algo in SET_POLICY_HYPERPARAMS:
        hyper.update({k: (dict(v) if isinstance(v, dict) else v) for k, v in SET_POLICY_HYPERPARAMS[algo].items()})
    return hyper


def default_settings(env_id: str) -> dict:
    """The run settings ``train.py rl`` starts from for ``env_id`` (:data:`DEFAULT_SETTINGS`, with
    :data:`SATELLITE_NORMALIZE` on the per-satellite envs)."""
    import envs
    settings = {**DEFAULT_SETTINGS, "env_kwargs": dict(DEFAULT_SETTINGS["env_kwargs"])}
    if env_id in envs.SATELLITE_ENV_IDS:
        settings["normalize"] = dict(SATELLITE_NORMALIZE)
    return settings


def resolve_policy(policy):
    """SB3's policy argument: an alias (``'MlpPolicy'``) as is, a dotted path (``'agents.set_policy.ChannelSetPolicy'``,
    as RL Zoo takes it) imported; ``ValueError`` when it cannot be."""
    if not isinstance(policy, str) or "." not in policy:
        return policy
    import importlib
    mod, _, name = policy.rpartition(".")
    try:
        return getattr(importlib.import_module(mod), name)
    except (ImportError, AttributeError) as e:
        raise ValueError(f"policy {policy!r} cannot be imported: {e}") from None


def normalize_kwargs(normalize) -> dict | None:
    """``VecNormalize``'s ``norm_obs`` / ``norm_reward`` of a ``normalize`` setting (``true``, ``false`` or a mapping
    of those two, as RL Zoo takes it), None for no normalization; ``ValueError`` otherwise."""
    if isinstance(normalize, bool):
        return dict(norm_obs=True, norm_reward=True) if normalize else None
    if isinstance(normalize, dict) and set(normalize) <= {"norm_obs", "norm_reward"} and all(
            isinstance(v, bool) for v in normalize.values()):
        kw = {"norm_obs": True, "norm_reward": True, **normalize}
        return kw if (kw["norm_obs"] or kw["norm_reward"]) else None
    raise ValueError(f"normalize must be true, false or a mapping of norm_obs / norm_reward to true / false, got "
                     f"{normalize!r}")


DEFAULT_SETTINGS = dict(n_timesteps=100_000, n_envs=16, normalize=True, env_kwargs={}, eval_freq=10_000,
                        eval_episodes=16, torch_threads=1, prefetch_worlds=2)
"""Run settings of ``train.py rl`` without ``--quick`` or a config file (``hyperparams/*.yml`` repeat them for
RL Zoo). ``torch_threads``: the policies are small (64-unit layers, a 32-unit LSTM), where torch's
intra-op threads cost more than they give: on 2 busy cores RecurrentPPO's quick preset ran at 48 env-steps/s
with torch's default 2 threads and 282 with 1 (``benchmarks/bench_recurrent.py``); applied with
:func:`set_torch_threads`, which keeps numba's kernels from resetting it. ``prefetch_worlds``: the training env draws
the worlds of its next two automatic resets ahead in a background process at the lowest CPU priority
(:class:`envs.prefetch.WorldPrefetcher`; the same episodes, drawn while the single-threaded gradient epochs leave
a core idle), and so does the evaluation env, for the resets of its evaluations; 0 turns it off."""
QUICK = dict(n_timesteps=24_576, n_envs=8, env_kwargs=dict(episode_length_s=60.0), eval_freq=1536, eval_episodes=8,
             hyper=dict(ppo=dict(n_steps=64, batch_size=256, n_epochs=5),
                        recurrentppo=dict(n_steps=128, batch_size=512, n_epochs=5),
                        sac=dict(learning_starts=512), td3=dict(learning_starts=512)))


def set_torch_threads(n: int) -> None:
    """Run torch's intra-op work on ``n`` threads from now on, leaving numba's kernels their own threads.

    Numba's ``omp`` threading layer and torch share one OpenMP runtime (libgomp). When numba starts that
    layer, at the first parallel kernel a process runs (the envs' kernels are parallel from
    ``PARALLEL_MIN_BATCH`` = 64 rows), it calls ``omp_set_num_threads(NUMBA_NUM_THREADS)`` once, which is
    also torch's intra-op thread count: a ``torch.set_num_threads(n)`` made before then is silently undone for
    the rest of the run (the policy's forward passes and ``train()`` ran on 2 threads with ``n = 1``). This
    starts numba's threading layer first (``numba.get_num_threads`` does; nothing when it is running already)
    and then sets torch's count, which holds: numba's later launches pass their own thread count to each
    parallel region (``num_threads`` clause) and change neither torch's count nor take it.

    Measured (PPO at n_envs 64 with :data:`DEFAULT_HYPERPARAMS`, one process, the three states interleaved,
    2 cores shared with other work): 1 torch thread 1278 env-steps/s (median of 4 rollouts, ``train()`` 0.8-1.2
    s per rollout), the silently overridden state 534 (``train()`` 5-10 s), torch on 2 threads 308 (``train()``
    11-37 s); in rounds with the cores less busy all three ran at 3850-4520.

    Parameters
    ----------
    n : torch's intra-op threads (``torch.set_num_threads``), >= 1.
    """
    import numba
    import torch

    numba.get_num_threads()  # starts numba's threading layer (its one-time omp_set_num_threads) before ours
    torch.set_num_threads(int(n))


def load_zoo_config(path, env_id: str) -> dict:
    """The entry for ``env_id`` of an RL Zoo style YAML hyperparameter file (``ValueError`` naming the file)."""
    import yaml
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        data = yaml.safe_load(path.read_bytes().decode("utf-8")) or {}
    except (UnicodeDecodeError, yaml.YAMLError) as e:
        raise ValueError(f"{path}: not valid YAML ({type(e).__name__}: {' '.join(str(e).split())})") from None
    if not isinstance(data, dict) or env_id not in data or not isinstance(data[env_id], dict):
        raise ValueError(f"{path}: no mapping for {env_id!r} (top-level keys: {sorted(data) if isinstance(data, dict) else data})")
    return dict(data[env_id])


MAX_TIMESTEPS = 10 ** 10
"""Most environment steps of one ``train.py rl`` run (``--timesteps``, ``n_timesteps``): about 23 days at the
~5000 env-steps/s of PPO here; more is a typo (``1e30``), not a run."""

HYPER_LIMITS = {
    "n_steps": (1, None), "batch_size": (1, None), "n_epochs": (1, None), "buffer_size": (1, None),
    "learning_starts": (0, None), "train_freq": (1, None), "policy_delay": (1, None),
    "target_update_interval": (1, None), "stats_window_size": (1, None), "gamma": (0.0, 1.0),
    "gae_lambda": (0.0, 1.0), "tau": (0.0, 1.0), "ent_coef": (0.0, None), "vf_coef": (0.0, None),
    "target_policy_noise": (0.0, None), "target_noise_clip": (0.0, None), "learning_rate": (0.0, None),
    "clip_range": (0.0, None), "clip_range_vf": (0.0, None), "max_grad_norm": (0.0, None), "target_kl": (0.0, None),
    "gradient_steps": (-1, None), "sde_sample_freq": (-1, None)}
"""Numeric hyperparameters of the SB3 algorithms and their ranges ``(low, high)`` (None: open), checked when the
value is a number: counts >= 1, discounts and ``gae_lambda`` / ``tau`` in [0, 1], coefficients >= 0
(``gradient_steps`` and ``sde_sample_freq`` take -1: "as many as steps" / "only at the start")."""


def _type_name(ann) -> str:
    """A readable form of a signature annotation (``int``, ``float | Callable[[float], float]``)."""
    import re
    return ann.__name__ if isinstance(ann, type) else re.sub(r"\b(?:[A-Za-z_]\w*\.)+(\w+)", r"\1", str(ann))


def _accepts(v, ann) -> bool:
    """Whether the YAML value ``v`` fits the annotation ``ann`` of an SB3 argument (unknown kinds: True)."""
    import collections.abc
    import inspect
    import types
    import typing
    if ann is inspect.Parameter.empty or ann is typing.Any or isinstance(ann, (str, typing.ForwardRef)):
        return True
    origin = typing.get_origin(ann)
    if origin in (typing.Union, types.UnionType):
        return any(_accepts(v, a) for a in typing.get_args(ann))
    simple = {type(None): v is None, bool: isinstance(v, bool), str: isinstance(v, str),
              int: isinstance(v, int) and not isinstance(v, bool),
              float: isinstance(v, (int, float)) and not isinstance(v, bool)}
    if ann in simple:
        return simple[ann]
    if ann is dict or origin is dict:
        return isinstance(v, dict)
    if ann is tuple or origin is tuple:
        return isinstance(v, (tuple, list))
    if origin is type:
        return isinstance(v, type)
    if ann is collections.abc.Callable or origin is collections.abc.Callable:
        return callable(v)
    return isinstance(v, ann) if isinstance(ann, type) else True


def check_hyperparameters(algo: str, hyper: dict, settings: dict, config_file=None) -> None:
    """Before any work: every hyperparameter must be an argument of the algorithm's class, of the type its
    signature declares (``n_steps: 64.5`` or ``gamma: "high"`` are refused here, not by SB3's assertions after
    the envs are built) and within :data:`HYPER_LIMITS`; the run settings whole numbers >= 1 (``n_timesteps`` at
    most :data:`MAX_TIMESTEPS`); ``ValueError`` naming the config file (or the defaults) and the key otherwise."""
    import inspect
    src = f"{config_file}: " if config_file is not None else ""
    sig = inspect.signature(algo_class(algo).__init__).parameters
    known = {p for p in sig if not p.startswith("_")} - {"self", "env"}
    bad = sorted(set(hyper) - known)
    try:
        resolve_policy(hyper.get("policy"))
    except ValueError as e:
        raise ValueError(f"{src}{e}") from None
    if bad:
        raise ValueError(f"{src}unknown hyperparameter(s) {', '.join(map(repr, bad))} for {algo}; known: "
                         f"{', '.join(sorted(known))} and the run settings n_timesteps, n_envs, normalize, "
                         "eval_freq, eval_episodes, env_kwargs, torch_threads, prefetch_worlds")
    for k, v in hyper.items():
        if not _accepts(v, sig[k].annotation):
            raise ValueError(f"{src}{k} must be {_type_name(sig[k].annotation)} for {algo} (stable-baselines3's "
                             f"signature), got {v!r}")
        lo, hi = HYPER_LIMITS.get(k, (None, None))
        if isinstance(v, (int, float)) and not isinstance(v, bool) and (
                (lo is not None and v < lo) or (hi is not None and v > hi) or v != v):
            raise ValueError(f"{src}{k} must be " + (f"in [{lo}, {hi}]" if hi is not None else f">= {lo}")
                             + f", got {v!r}")
    if algo in ("ppo", "recurrentppo") and hyper.get("normalize_advantage", True) and hyper.get("batch_size") == 1:
        raise ValueError(f"{src}batch_size must be >= 2 for {algo} with normalize_advantage (the advantages of "
                         "one sample cannot be normalized), got 1")
    for k in ("n_timesteps", "n_envs", "eval_freq", "eval_episodes"):
        v = settings[k]
        try:
            ok = not isinstance(v, bool) and float(v) >= 1 and float(v) == int(float(v))
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise ValueError(f"{src}{k} must be a whole number >= 1, got {v!r}")
    if float(settings["n_timesteps"]) > MAX_TIMESTEPS:
        raise ValueError(f"{src}n_timesteps must be at most {MAX_TIMESTEPS:.0e} (about 23 days at 5000 env-steps/s), "
                         f"got {settings['n_timesteps']!r}")
    try:
        normalize_kwargs(settings["normalize"])
    except ValueError as e:
        raise ValueError(f"{src}{e}") from None


class _ProgressBar:
    """A tqdm progress bar over timesteps as an SB3 callback (no dependency on 'rich')."""

    def __new__(cls, total):
        from stable_baselines3.common.callbacks import BaseCallback
        from tqdm import tqdm

        class Bar(BaseCallback):
            def _on_training_start(self):
                self.bar = tqdm(total=total, unit="step", desc="train", dynamic_ncols=True, mininterval=1.0)
                self.done = 0

            def _on_step(self):
                self.bar.update(self.num_timesteps - self.done)  # tqdm rate-limits the redraws
                self.done = self.num_timesteps
                return True

            def _on_training_end(self):
                self.bar.update(self.num_timesteps - self.done)
                self.bar.close()

        return Bar()


class _SaveNormalization:
    """An SB3 callback for ``EvalCallback(callback_on_new_best=...)``: saves the training env's observation
    statistics (its ``VecNormalize``, if any) to ``path`` when a new best model is saved, so that
    ``best/best_model.zip`` is evaluated on the observations it was chosen on (:meth:`Sb3Policy.load`)."""

    def __new__(cls, path):
        from stable_baselines3.common.callbacks import BaseCallback

        class Save(BaseCallback):
            def _on_step(self):
                vn = self.model.get_vec_normalize_env()
                if vn is not None:
                    with atomic_path(path) as tmp:
                        vn.save(str(tmp))
                return True

        return Save()


def resolve_settings(env_id: str, algo: str, timesteps=None, n_envs=None, env_kwargs=None, config_file=None,
                     quick: bool = False, normalize=None, eval_episodes=None) -> tuple[dict, dict]:
    """``(hyperparameters, run settings)`` of :func:`train_rl` (module docstring: defaults, ``--quick``, the
    config file, the arguments; later wins), every one checked (:func:`check_hyperparameters`, the env's
    arguments and method) before any work; ``ValueError`` naming the config file and the key."""
    from envs.core import check_method_has_params
    from .rollout import env_class

    hyper = default_hyperparams(algo, env_id)
    settings = default_settings(env_id)
    if quick:
        settings.update(n_timesteps=QUICK["n_timesteps"], n_envs=QUICK["n_envs"], eval_freq=QUICK["eval_freq"],
                        eval_episodes=QUICK["eval_episodes"], env_kwargs=dict(QUICK["env_kwargs"]))
        hyper.update(QUICK["hyper"].get(algo, {}))
    if config_file is not None:
        zoo = load_zoo_config(config_file, env_id)
        for k in ("n_timesteps", "n_envs", "normalize", "eval_freq", "eval_episodes", "torch_threads",
                  "prefetch_worlds"):
            if k in zoo:
                settings[k] = zoo.pop(k)
        zkw = zoo.pop("env_kwargs", {}) or {}
        if not isinstance(zkw, dict):
            raise ValueError(f"{config_file}: env_kwargs must be a mapping, got {zkw!r}")
        settings["env_kwargs"].update(zkw)
        hyper.update(zoo)
    if timesteps is not None:
        settings["n_timesteps"] = int(timesteps)
    if n_envs is not None:
        settings["n_envs"] = int(n_envs)
    if normalize is not None:
        settings["normalize"] = bool(normalize)
    if eval_episodes is not None:
        settings["eval_episodes"] = int(eval_episodes)
    settings["env_kwargs"].update(env_kwargs or {})
    check_hyperparameters(algo, hyper, settings, config_file)
    cls = env_class(env_id)
    try:
        cfg = cls.config_from(settings["env_kwargs"])
        if cls.PARAMS:  # an env of an adaptive law's knob: the method must run that law
            check_method_has_params(cfg.method, cls.PARAMS, cls.DEFAULTS["method"])
    except ValueError as e:
        raise ValueError(f"{config_file or 'env_kwargs'}: {e}") from None
    settings["n_timesteps"] = int(float(settings["n_timesteps"]))
    if settings["n_timesteps"] < 1 or settings["n_envs"] < 1:
        raise ValueError("--timesteps and --n-envs must be positive")
    if not isinstance(settings["torch_threads"], int) or settings["torch_threads"] < 1:
        raise ValueError(f"torch_threads must be an int >= 1, got {settings['torch_threads']!r}")
    pf = settings["prefetch_worlds"]
    if isinstance(pf, bool) or not isinstance(pf, int) or pf < 0:
        raise ValueError(f"{config_file or 'settings'}: prefetch_worlds must be an int >= 0 (worlds drawn ahead; "
                         f"0: off), got {pf!r}")
    return hyper, settings


def train_rl(env_id: str, algo: str, out, timesteps: int | None = None, seed: int = 0, n_envs: int | None = None,
             env_kwargs: dict | None = None, config_file=None, quick: bool = False, normalize: bool | None = None,
             progress: bool = True, eval_episodes: int | None = None) -> dict:
    """Train ``algo`` on ``env_id``; writes ``out/model.zip`` and ``out/config.json``; returns the config."""
    import envs  # noqa: F401
    from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from envs.sb3 import make_sb3_vec_env
    from .rollout import env_class

    algo = algo.lower()
    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r}; known: {', '.join(ALGOS)}")
    env_class(env_id)
    hyper, settings = resolve_settings(env_id, algo, timesteps=timesteps, n_envs=n_envs, env_kwargs=env_kwargs,
                                       config_file=config_file, quick=quick, normalize=normalize,
                                       eval_episodes=eval_episodes)

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ekw = settings["env_kwargs"]
    venv = VecMonitor(make_sb3_vec_env(env_id, settings["n_envs"], seed=seed * 10_007,
                                       prefetch_worlds=settings["prefetch_worlds"], **ekw))
    n_eval = max(1, min(settings["eval_episodes"], 16))
    # the evaluation env is reset at every evaluation and its rows end together: its coming worlds are drawn ahead
    # too (a reset without a seed continues its rows' streams, envs.vector_env)
    eval_env = VecMonitor(make_sb3_vec_env(env_id, n_eval, seed=EVAL_SEED_OFFSET + 1000 * seed,
                                           prefetch_worlds=settings["prefetch_worlds"], **ekw))
    norm = normalize_kwargs(settings["normalize"])
    if norm is not None:
        venv = VecNormalize(venv, **norm, gamma=hyper.get("gamma", 0.99))
        eval_env = VecNormalize(eval_env, norm_obs=norm["norm_obs"], norm_reward=False, training=False)
    set_torch_threads(settings["torch_threads"])
    cls = algo_class(algo)
    policy = hyper.pop("policy")
    try:
        model = cls(resolve_policy(policy), venv, seed=seed, device="cpu", verbose=0, **hyper)
    except (AssertionError, ValueError, TypeError) as e:  # what the checks above cannot see (combinations)
        venv.close()
        eval_env.close()
        raise ValueError(f"{config_file or 'hyperparameters'}: stable-baselines3 refused the {algo} hyperparameters "
                         f"({type(e).__name__}: {' '.join(str(e).split())})") from None
    # SB3 seeds the env it is given with the algorithm's seed (BaseAlgorithm.set_random_seed: env.seed(seed)), which
    # made the training worlds of seed s + 1 those of seed s shifted by one row: the training env keeps its own base
    venv.seed(seed * 10_007)
    fmt = ["csv"]
    try:
        import tensorboard  # noqa: F401
        fmt.append("tensorboard")
    except ImportError:
        pass
    model.set_logger(configure(str(out / "logs"), fmt))
    # evaluate at least 4 times and checkpoint at least twice per run, however short (a 2048-step run with
    # the 10000-step default would write neither best/ nor checkpoints/)
    settings["eval_freq"] = int(min(settings["eval_freq"], max(settings["n_timesteps"] // 4, settings["n_envs"])))
    per_env = max(settings["eval_freq"] // settings["n_envs"], 1)
    save_freq = max(min(per_env * 4, settings["n_timesteps"] // settings["n_envs"] // 2), 1)
    callbacks = [
        EvalCallback(eval_env, n_eval_episodes=n_eval, eval_freq=per_env, best_model_save_path=str(out / "best"),
                     log_path=str(out / "eval"), deterministic=True, verbose=0,
                     callback_on_new_best=_SaveNormalization(out / "best" / "vecnormalize.pkl")),
        CheckpointCallback(save_freq=save_freq, save_path=str(out / "checkpoints"), name_prefix="model",
                           save_vecnormalize=norm is not None),
    ]
    if progress:
        callbacks.append(_ProgressBar(settings["n_timesteps"]))
    config = {"env": env_id, "algo": algo, "seed": seed, "env_kwargs": ekw, "policy": policy,
              "hyperparameters": hyper, **{k: v for k, v in settings.items() if k != "env_kwargs"},
              "train_seed_base": seed * 10_007, "eval_seed_base": EVAL_SEED_OFFSET + 1000 * seed}
    write_atomic(out / "config.json", dumps(config, indent=2, default=str))
    write_atomic(out / INCOMPLETE, f"training started {time.strftime('%Y-%m-%d %H:%M:%S')} and has not finished "
                                   "(this file is removed when it does)\n")
    t0 = time.perf_counter()
    try:
        _learn(model, settings["n_timesteps"], callbacks, out, config)
    finally:
        wall = time.perf_counter() - t0
        venv.close()  # stops the world prefetch process (a sweep runs many of these in one process)
        eval_env.close()
    with atomic_path(out / "model.zip") as tmp:
        model.save(str(tmp))
    if norm is not None:
        with atomic_path(out / "vecnormalize.pkl") as tmp:
            venv.save(str(tmp))
    config["wall_time_s"] = wall
    config["env_steps_per_s"] = settings["n_timesteps"] / wall
    ev = out / "eval" / "evaluations.npz"
    if ev.is_file():
        d = np.load(ev)
        config["eval_mean_reward_last"] = float(d["results"][-1].mean())
        config["eval_mean_reward_best"] = float(d["results"].mean(1).max())
    config["status"] = "complete"
    write_atomic(out / "config.json", dumps(config, indent=2, default=str))
    (out / INCOMPLETE).unlink(missing_ok=True)
    return config


INCOMPLETE = "INCOMPLETE"
"""The file in a run folder whose training has not finished: written when the training starts, its text replaced
by what was kept at a Ctrl-C (:class:`TrainingInterrupted`), removed when the training ends normally."""


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`train_rl`: the run folder is marked incomplete (its ``INCOMPLETE`` file and
    ``config.json``'s ``status``); the message names the folder, the step reached and what was kept."""


def _learn(model, n_timesteps: int, callbacks: list, out: Path, config: dict) -> None:
    """``model.learn`` with the callbacks; at a Ctrl-C the progress bar is closed, ``config.json`` gets
    ``status: interrupted`` and ``completed_timesteps``, ``INCOMPLETE`` says what is kept (``best/``,
    ``checkpoints/``: written by the callbacks as the training went) and :class:`TrainingInterrupted` is raised."""
    from stable_baselines3.common.callbacks import CallbackList
    try:
        model.learn(total_timesteps=n_timesteps, callback=CallbackList(callbacks))
    except KeyboardInterrupt:
        for cb in callbacks:
            bar = getattr(cb, "bar", None)
            if bar is not None:
                bar.close()
        done = int(model.num_timesteps)
        kept = [f"{d}/" for d in ("best", "checkpoints") if (out / d).is_dir() and any((out / d).iterdir())]
        stale = " (the model.zip here is an earlier run's)" if (out / "model.zip").exists() else ""
        text = (f"training interrupted (Ctrl-C) at step {done} of {n_timesteps}: model.zip not written{stale}; "
                f"kept: {', '.join(kept) or 'nothing trained yet'}")
        config.update(status="interrupted", completed_timesteps=done)
        write_atomic(out / "config.json", dumps(config, indent=2, default=str))
        write_atomic(out / INCOMPLETE, text + "\n")
        raise TrainingInterrupted(f"{out} is incomplete: {text}") from None
