"""train.py rl settings: torch_threads and prefetch_worlds from a config file are validated before any work;
torch_threads holds for torch's work during training even after the env's parallel numba kernels have started
numba's threading layer."""
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from agents.training import train_rl
from nav_filters.kernels import PARALLEL_MIN_BATCH

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("key, value, message", [
    *[("torch_threads", v, "torch_threads must be an int >= 1") for v in ("0", "2.5", "many")],
    *[("prefetch_worlds", v, "prefetch_worlds must be an int >= 0") for v in ("-1", "2.5", "true")]])
def test_run_settings_are_checked_before_any_work(tmp_path, key, value, message):
    cfg = tmp_path / "c.yml"
    cfg.write_text(f"GnssIns/SageHusa-v1:\n  {key}: {value}\n")
    with pytest.raises(ValueError, match=message):
        train_rl("GnssIns/SageHusa-v1", "ppo", tmp_path / "out", config_file=cfg, progress=False)
    assert not (tmp_path / "out").exists()


CHILD = textwrap.dedent("""
    import json, sys
    import numba, torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.policies import ActorCriticPolicy
    from agents.training import train_rl

    seen = {"forward": set(), "train": set()}
    forward, train = ActorCriticPolicy.forward, PPO.train

    def counted_forward(self, *a, **k):
        seen["forward"].add(torch.get_num_threads())
        return forward(self, *a, **k)

    def counted_train(self):
        seen["train"].add(torch.get_num_threads())
        return train(self)

    ActorCriticPolicy.forward, PPO.train = counted_forward, counted_train
    train_rl("GnssIns/SageHusa-v1", "ppo", sys.argv[1], config_file=sys.argv[2], progress=False)
    print(json.dumps({"numba": numba.get_num_threads(), **{k: sorted(v) for k, v in seen.items()}}))
""")


def test_torch_threads_hold_after_numba_parallel_kernels(tmp_path):
    """In a fresh process (numba's threading layer not yet started; in this one earlier tests may have started
    it), a PPO run at n_envs >= PARALLEL_MIN_BATCH (the env's kernels run parallel, on numba's 2 threads) sees
    torch at the configured 1 thread in every policy forward pass and in ``train()``. Before the fix numba's
    start (its one-time ``omp_set_num_threads(2)`` in the OpenMP runtime torch shares) set torch to 2 from the
    first env step on: forward passes [1, 2], train [2]."""
    n_envs = 64
    assert n_envs >= PARALLEL_MIN_BATCH
    cfg = tmp_path / "c.yml"
    cfg.write_text("GnssIns/SageHusa-v1:\n"
                   f"  n_envs: {n_envs}\n  n_timesteps: {2 * n_envs}\n  n_steps: 2\n  batch_size: {n_envs}\n"
                   "  n_epochs: 1\n  normalize: false\n  eval_episodes: 1\n  torch_threads: 1\n"
                   "  env_kwargs: {episode_length_s: 5.0}\n")
    env = dict(os.environ, NUMBA_NUM_THREADS="2", PYTHONPATH=os.pathsep.join(
        [str(ROOT)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    p = subprocess.run([sys.executable, "-c", CHILD, str(tmp_path / "out"), str(cfg)], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    seen = json.loads(p.stdout.strip().splitlines()[-1])
    assert seen == {"numba": 2, "forward": [1], "train": [1]}


def test_ppo_default_uses_torchs_fused_adam():
    """The PPO defaults (and hyperparams/ppo.yml, tests/scripts/test_zoo.py) reach torch: SB3 builds the policy's
    Adam with ``fused=True`` (one kernel per step for all parameters), with the default learning rate."""
    from stable_baselines3 import PPO

    from agents.training import DEFAULT_HYPERPARAMS
    from envs.sb3 import make_sb3_vec_env

    hp = dict(DEFAULT_HYPERPARAMS["ppo"])
    model = PPO(hp.pop("policy"), make_sb3_vec_env("GnssIns/SageHusa-v1", 2, seed=0, episode_length_s=10.0),
                device="cpu", **hp)
    opt = model.policy.optimizer
    assert type(opt).__name__ == "Adam" and opt.defaults["fused"] is True
    assert opt.param_groups[0]["lr"] == hp["learning_rate"]



def test_the_evaluations_of_a_run_repeat_with_its_seed(tmp_path):
    """SB3's EvalCallback resets the evaluation env at every evaluation; that reset continues the env's seeded
    streams (envs.vector_env), so two runs with one seed log the same evaluation returns, every one of them.
    Before, each reset after the first drew its rows' worlds from the OS: only the first evaluation repeated."""
    import numpy as np

    cfg = tmp_path / "c.yml"
    cfg.write_text("GnssIns/SageHusa-v1:\n  n_envs: 2\n  n_timesteps: 64\n  n_steps: 8\n  batch_size: 16\n"
                   "  n_epochs: 1\n  eval_episodes: 2\n  prefetch_worlds: 0\n  env_kwargs: {episode_length_s: 4.0}\n")
    runs = []
    for k in range(2):
        train_rl("GnssIns/SageHusa-v1", "ppo", tmp_path / f"run{k}", config_file=cfg, seed=3, progress=False)
        runs.append(np.load(tmp_path / f"run{k}" / "eval" / "evaluations.npz")["results"])
    assert runs[0].shape[0] >= 3  # several evaluations
    np.testing.assert_array_equal(runs[0], runs[1])


def test_the_training_worlds_keep_their_seed_base_after_sb3_seeds_the_env(tmp_path, monkeypatch):
    """SB3 seeds the env it trains on with the algorithm's seed; train_rl seeds it back to its own base
    (``seed * 10_007``, in config.json), so the rows of seeds s and s + 1 draw apart streams (before: row i of
    seed s + 1 was row i + 1 of seed s). The evaluation env keeps its base too."""
    from envs.vector_env import GnssInsTuningVectorEnv

    seen = []
    seed_rows = GnssInsTuningVectorEnv._seed_rows

    def record(self, seed):
        seen.append(seed)
        return seed_rows(self, seed)

    monkeypatch.setattr(GnssInsTuningVectorEnv, "_seed_rows", record)
    cfg = tmp_path / "c.yml"
    cfg.write_text("GnssIns/SageHusa-v1:\n  n_envs: 2\n  n_timesteps: 16\n  n_steps: 8\n  batch_size: 16\n"
                   "  n_epochs: 1\n  eval_episodes: 1\n  prefetch_worlds: 0\n  env_kwargs: {episode_length_s: 4.0}\n")
    config = train_rl("GnssIns/SageHusa-v1", "ppo", tmp_path / "run", config_file=cfg, seed=3, progress=False)
    assert seen[0] == config["train_seed_base"] == 3 * 10_007  # the training env's first reset
    assert config["eval_seed_base"] in seen and 3 not in seen


def test_best_and_checkpoint_models_load_with_the_statistics_they_were_saved_with(tmp_path):
    """A run with normalized observations saves them with best/best_model.zip (at each new best) and with every
    checkpoint; Sb3Policy.load finds them and the run's config.json. A model trained on normalized observations
    whose statistics are missing is an error naming the file (before: it loaded and saw raw observations)."""
    import pickle

    import numpy as np

    from agents.policies import Sb3Policy

    cfg = tmp_path / "c.yml"
    cfg.write_text("GnssIns/SageHusa-v1:\n  n_envs: 2\n  n_timesteps: 64\n  n_steps: 8\n  batch_size: 16\n"
                   "  n_epochs: 1\n  eval_episodes: 1\n  prefetch_worlds: 0\n  env_kwargs: {episode_length_s: 4.0}\n")
    out = tmp_path / "run"
    train_rl("GnssIns/SageHusa-v1", "ppo", out, config_file=cfg, seed=0, progress=False)
    best = Sb3Policy.load(out / "best" / "best_model.zip", "ppo")
    with open(out / "best" / "vecnormalize.pkl", "rb") as f:
        saved = pickle.load(f)
    np.testing.assert_array_equal(best.obs_rms.mean, saved.obs_rms.mean)
    assert best.env_id == "GnssIns/SageHusa-v1"  # the run's config.json, one folder up
    ckpt = sorted((out / "checkpoints").glob("model_*_steps.zip"))[0]
    steps = ckpt.stem.split("_")[1]
    with open(out / "checkpoints" / f"model_vecnormalize_{steps}_steps.pkl", "rb") as f:
        saved = pickle.load(f)
    np.testing.assert_array_equal(Sb3Policy.load(ckpt, "ppo").obs_rms.var, saved.obs_rms.var)
    (out / "best" / "vecnormalize.pkl").unlink()
    with pytest.raises(ValueError, match=r"normalized observations .*best/vecnormalize\.pkl"):
        Sb3Policy.load(out / "best" / "best_model.zip", "ppo")
