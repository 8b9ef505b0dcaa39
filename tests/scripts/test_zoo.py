"""RL Zoo out of the box: hyperparams/*.yml hold navgym's own hyperparameters, rl_zoo3 trains and enjoys with them."""
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import envs
from envs.config import EnvConfig
from agents.training import default_hyperparams, default_settings, load_zoo_config

ROOT = Path(__file__).resolve().parents[2]
FILES = {"ppo": "ppo.yml", "recurrentppo": "recurrentppo.yml", "sac": "sac.yml"}


@pytest.mark.parametrize("algo", sorted(FILES))
def test_hyperparameter_files_are_navgyms_own(algo):
    path = ROOT / "hyperparams" / FILES[algo]
    assert set(yaml.safe_load(path.read_text())) == set(envs.ENV_IDS)
    for env_id in envs.ENV_IDS:
        zoo = load_zoo_config(path, env_id)  # what train.py rl --config reads
        for k in ("n_timesteps", "n_envs", "normalize"):
            assert zoo.pop(k) == default_settings(env_id)[k], (env_id, k)
        assert zoo.pop("env_kwargs") == {"episode_length_s": EnvConfig().episode_length_s}
        assert zoo == default_hyperparams(algo, env_id), env_id
    for env_id in envs.SATELLITE_ENV_IDS:  # the set policies, observations not normalized
        assert load_zoo_config(path, env_id)["policy"].startswith("agents.set_policy.")
        assert load_zoo_config(path, env_id)["normalize"] == {"norm_obs": False, "norm_reward": True}


def _zoo(*args, cwd):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300)


@pytest.mark.parametrize("env_id", ["GnssIns/SageHusa-v1", "GnssIns/SatelliteR-v0"])
def test_rl_zoo_trains_and_enjoys_with_the_shipped_file(tmp_path, env_id):
    """RL Zoo with hyperparams/ppo.yml: the scalar env, and a per-satellite env with its set policy (imported by
    name from agents.set_policy)."""
    pytest.importorskip("rl_zoo3", reason="RL Zoo is the 'zoo' extra (scripts/setup.sh installs it)")
    logs = tmp_path / "logs"
    name = env_id.replace("/", "-")
    p = _zoo("rl_zoo3.train", "--gym-packages", "envs", "--env", env_id, "--algo", "ppo",
             "--conf-file", str(ROOT / "hyperparams" / "ppo.yml"), "-n", "256", "-f", str(logs), "--seed", "0",
             "--env-kwargs", "episode_length_s:10.0", "--hyperparams", "n_envs:2", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    run = logs / "ppo" / f"{name}_1"
    assert (run / f"{name}.zip").is_file()
    assert (run / name / "vecnormalize.pkl").is_file()  # normalize: true (rewards only on the per-satellite env)
    saved = dict(yaml.unsafe_load((run / name / "config.yml").read_text()))  # an OrderedDict
    assert saved["gamma"] == 0.95 and saved["n_envs"] == 2 and saved["n_steps"] == 128
    q = _zoo("rl_zoo3.enjoy", "--gym-packages", "envs", "--env", env_id, "--algo", "ppo", "-f",
             str(logs), "--exp-id", "1", "-n", "20", "--no-render", "--env-kwargs", "episode_length_s:10.0",
             cwd=tmp_path)
    assert q.returncode == 0, q.stderr[-3000:]
    assert "Episode Length 10" in q.stdout and "Mean reward" in q.stdout
