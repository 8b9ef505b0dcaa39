"""train.py: a quick-scale RL run writes a loadable model and config; tune writes a usable tuning file;
CLI errors are one line with exit code 2; the RL Zoo import path registers the ids."""
import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def run(script, *args):
    return subprocess.run([sys.executable, str(ROOT / script), *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=900)


def test_rl_smoke_writes_a_loadable_model_and_eval_runs_it(tmp_path):
    out = tmp_path / "run"
    p = run("train.py", "rl", "--env", "GnssIns/SageHusa-v1", "--algo", "ppo", "--timesteps", "256",
            "--n-envs", "4", "--env-kwargs", "episode_length_s=6", "--seed", "1", "--no-progress", "--out", str(out))
    assert p.returncode == 0, p.stderr[-2000:]
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["env"] == "GnssIns/SageHusa-v1" and cfg["n_timesteps"] == 256 and cfg["env_kwargs"]["episode_length_s"] == 6
    for f in ("model.zip", "vecnormalize.pkl", "best/best_model.zip"):
        assert (out / f).stat().st_size > 0
    assert list((out / "checkpoints").glob("model_*_steps.zip"))  # a short run still evaluates and checkpoints
    assert cfg["eval_freq"] <= 64
    from agents.policies import Sb3Policy
    pol = Sb3Policy.load(out / "model.zip", "ppo")
    pol.reset(3)
    from envs.core import OBS_FEATURES
    a = pol.act(np.zeros((3, 1 + len(OBS_FEATURES)), np.float32))
    assert a.shape == (3, 1) and np.all(np.abs(a) <= 1.0 + 1e-6)
    e = run("eval.py", "--scenario", "seed000-sim", "--methods", f"kf,ppo:{out / 'model.zip'}", "--episodes", "2",
            "--out", str(tmp_path / "ev"), "--no-plots")
    assert e.returncode == 0, e.stderr[-2000:]
    res = json.loads((tmp_path / "ev" / "results.json").read_text())["scenarios"]["seed000-sim"]
    assert res[f"ppo:{out / 'model.zip'}"]["episodes"] == 2 and np.isfinite(res[f"ppo:{out / 'model.zip'}"]["rmse_h_m"])


def test_tune_writes_a_tuning_file_that_eval_reads(tmp_path):
    p = run("train.py", "tune", "--env", "GnssIns/SageHusa-v1", "--env-kwargs", "episode_length_s=10",
            "--n-train", "2", "--grid-size", "3", "--out", str(tmp_path))
    assert p.returncode == 0, p.stderr[-2000:]
    t = json.loads((tmp_path / "tuning.json").read_text())
    assert len(t["grid"]) == 3 and t["best"] in t["grid"] and t["best_rmse_h_m"] == min(t["rmse_h_m"])
    assert min(t["train_seeds"]) >= 500_000  # disjoint from eval.py's episode seeds
    from agents.methods import parse_method_spec
    m = parse_method_spec(f"tuned:{tmp_path / 'tuning.json'}")
    assert m.method == "sage-husa" and m.params["b"] == t["best"]
    # a line per grid value on stderr, the ETA from the second value on (the first pays the compilation)
    lines = [x for x in p.stderr.splitlines() if x.startswith("tune: b = ")]
    assert len(lines) == 3 and [f"({i}/3)" in x for i, x in enumerate(lines, 1)] == [True] * 3
    assert lines[0].endswith("; ETA after the next value") and "; ETA " in lines[1] and "ETA" not in lines[2]
    assert f"RMSE {t['rmse_h_m'][0]:.3f} m" in lines[0]
    assert "best b = " in p.stdout


def test_tune_progress_line_eta_leaves_out_the_first_value():
    from agents.tuning import progress_line
    assert progress_line("b", 0.5, 0, 5, 1.234, 0, 8, [100.0]) == (
        "tune: b = 0.5 (1/5): RMSE 1.234 m in 2 min; ETA after the next value")
    assert progress_line("b", 0.9, 2, 5, 1.0, 2, 8, [300.0, 30.0, 50.0]).endswith(
        "RMSE 1.000 m, 2 of 8 diverged in 50 s; ETA 80 s")  # 2 values left x 40 s, not counting the first
    assert progress_line("b", 0.99, 4, 5, 1.0, 0, 8, [1.0] * 5).endswith("in 1 s")


@pytest.mark.parametrize("args, msg", [
    (("rl", "--env", "GnssIns/Nope-v0", "--out", "x"), "unknown environment"),
    (("rl", "--algo", "dqn", "--out", "x"), "unknown algorithm"),
    (("rl", "--env-kwargs", "scenaro=urban", "--out", "x"), "unknown environment argument"),
    (("rl", "--env-kwargs", "reward=money", "--out", "x"), "reward"),
    (("tune", "--param", "q", "--out", "x"), "no parameter"),
    (("tune", "--seed", "-1", "--out", "x"), "--seed must be >= 0"),
    (("rl", "--seed", "-1", "--out", "x"), "--seed must be >= 0"),
    (("zupt", "--model", "mlp", "--seed", "-1", "--out", "x"), "--seed must be >= 0"),
    (("rl", "--timesteps", "nan", "--out", "x"), "--timesteps must be a finite number"),
    (("rl", "--n-envs", "0", "--out", "x"), "--n-envs must be >= 1"),
    (("tune", "--n-train", "0", "--out", "x"), "--n-train must be >= 1"),
    (("tune", "--grid-size", "0", "--out", "x"), "--grid-size must be >= 2"),
    (("tune", "--env-kwargs", "method=kf", "episode_length_s=5", "--n-train", "1", "--grid-size", "2", "--out", "x"),
     "method 'kf' does not take the parameter(s) b this env sets"),
    (("rl", "--out", "README.md"), "is a file, not a directory"),
    (("learned-r", "--scenarios", "urban,mars", "--out", "x"), "--scenarios: LearnedRConfig.scenarios: 'mars' is not"),
    (("learned-r", "--scenarios", "smartloc-potsdamer-platz", "--out", "x"), "is not a simulated scenario"),
])
def test_train_cli_errors(args, msg):
    p = run("train.py", *args)
    assert p.returncode == 2 and msg in p.stderr and "Traceback" not in p.stderr


@pytest.mark.parametrize("args, msg", [
    (("--methods", "kf,ppo:/nonexistent/model.zip"), "model file not found"),
    (("--methods", "tuned:/nonexistent/tuning.json"), "tuning file not found"),
    (("--methods", "sage-husa[b=abc]"), "bad value"),
])
def test_eval_method_errors(args, msg, tmp_path):
    p = run("eval.py", *args, "--out", str(tmp_path))
    assert p.returncode == 2 and msg in p.stderr and "Traceback" not in p.stderr


def test_rl_zoo_import_path():
    """RL Zoo's --gym-packages envs imports the package; gymnasium's 'module:id' form does the same."""
    env = gym.make("envs:GnssIns/SageHusa-v1", episode_length_s=4.0)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
