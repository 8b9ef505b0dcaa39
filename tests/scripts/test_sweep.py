"""train.py sweep without Ray: the sweep file is checked before any work (one line naming the file and the
field, exit 2); the trials are the same for the same file; run folders never collide."""
import sys

import pytest

import train
from agents.sweep import configurations, expand_trials, load_sweep

BASE = """envs: [GnssIns/SageHusa-v1]
scenarios: [seed000-sim]
timesteps: 256
"""


def write(tmp_path, text):
    p = tmp_path / "sweep.yml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("extra, msg", [
    ("algo: [ppo]\n", "unknown key(s) ['algo']"),
    ("algos: [dqn]\n", "algos: unknown algorithm 'dqn'"),
    ("seeds: [0, -1]\n", "seeds: must be integers >= 0, got -1"),
    ("seeds: [0, 0]\n", "seeds: lists a value twice"),
    ("timesteps: 0\n", "timesteps: must be an integer >= 1, got 0"),
    ("random: {gamma: {normal: [0, 1]}}\n", "random.gamma: distribution must be one of"),
    ("random: {learning_rate: {loguniform: [0, 1.0e-3]}}\n", "random.learning_rate: loguniform needs lo > 0"),
    ("grid: {gamma: []}\n", "grid.gamma: must be a non-empty list"),
    ("grid: {gamma: [0.9]}\nhyperparams: {gamma: 0.9}\n", "['gamma'] given in more than one of them"),
    ("env_kwargs: {episode_lenght_s: 6}\n", "unknown environment argument(s) ['episode_lenght_s']"),
    ("run_dir: '{scenario}/{algo}'\n", "run_dir: '{scenario}/{algo}' must contain {seed}"),
    ("grid: {gamma: [0.9, 0.95]}\nrun_dir: '{algo}-s{seed}'\n", "gives two trials the same folder 'ppo-s0'"),
    ("eval: {baselines: [ukf]}\n", "eval.baselines: unknown filter method"),
])
def test_sweep_file_errors_are_one_line_exit_2(tmp_path, capsys, extra, msg):
    p = write(tmp_path, BASE + extra)
    with pytest.raises(SystemExit) as e:
        train.main(["sweep", "--config", str(p), "--out", str(tmp_path / "out")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and str(p) in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_sweep_backend_ray_without_ray_says_how_to_install(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(SystemExit) as e:
        train.main(["sweep", "--config", str(write(tmp_path, BASE)), "--out", str(tmp_path / "o"), "--backend", "ray"])
    assert e.value.code == 2
    assert "pip install 'navgym[distributed]'" in capsys.readouterr().err


def test_trials_are_grid_times_draws_times_seeds_and_reproducible(tmp_path):
    p = write(tmp_path, BASE + """seeds: [0, 1]
grid: {learning_rate: [3.0e-4, 1.0e-3]}
random: {gamma: {uniform: [0.9, 0.99]}, n_epochs: {choice: [5, 10]}}
samples: 3
hyperparams: {n_steps: 64}
run_dir: "{algo}{hp}-s{seed}"
""")
    cfg = load_sweep(p)
    confs = configurations(cfg)
    assert len(confs) == 6 and [c["learning_rate"] for c in confs] == [3e-4] * 3 + [1e-3] * 3
    assert all(0.9 <= c["gamma"] <= 0.99 and c["n_epochs"] in (5, 10) for c in confs)
    assert len({c["gamma"] for c in confs}) == 6  # independent draws
    trials = expand_trials(cfg, tmp_path / "out")
    assert len(trials) == 12 and len({t.out for t in trials}) == 12
    # the seeds replicate one configuration: same searched values, different seed
    assert trials[0].searched == trials[1].searched and (trials[0].seed, trials[1].seed) == (0, 1)
    assert trials[0].hyperparams == {"n_steps": 64, **confs[0]}
    assert trials[0].env_kwargs == {"scenario": "seed000-sim"}
    assert [t.run_dir for t in expand_trials(load_sweep(p), tmp_path / "out")] == [t.run_dir for t in trials]
    other = load_sweep(write(tmp_path, p.read_text() + "search_seed: 1\n"))
    assert configurations(other) != confs


def test_shipped_example_sweep_file_is_valid():
    from pathlib import Path
    cfg = load_sweep(Path(__file__).resolve().parents[2] / "configs" / "sweep.yml")
    assert len(expand_trials(cfg, "runs/sweep")) == 16


def test_shipped_small_sweep_file_is_valid_and_small():
    """configs/sweep_small.yml runs in minutes on 2 cores: two short PPO runs on short episodes."""
    from pathlib import Path
    cfg = load_sweep(Path(__file__).resolve().parents[2] / "configs" / "sweep_small.yml")
    trials = expand_trials(cfg, "runs/sweep_small")
    assert len(trials) == 2 and sum(t.timesteps for t in trials) <= 40_000
    assert cfg.env_kwargs["episode_length_s"] <= 60 and cfg.search == "grid"


def test_every_shipped_sweep_file_is_valid():
    """Every configs/*.yml sweep file loads (names, envs, methods checked by load_sweep) and expands to trials;
    the per-satellite one runs the set policy's env on top of kf-huber with 3 seeds."""
    from pathlib import Path
    files = sorted((Path(__file__).resolve().parents[2] / "configs").glob("*.yml"))
    assert len(files) >= 6
    for f in files:
        assert expand_trials(load_sweep(f), "runs/x"), f
    sat = expand_trials(load_sweep(files[0].parent / "satellite_r.yml"), "runs/satellite-r")
    assert [t.seed for t in sat] == [0, 1, 2] and {t.env for t in sat} == {"GnssIns/SatelliteR-v0"}
    assert all(t.env_kwargs["method"] == "kf-huber" for t in sat)


def test_a_run_finished_by_train_rl_with_the_same_settings_counts_as_done(tmp_path):
    import json
    from agents.sweep import trial_status
    cfg = load_sweep(write(tmp_path, BASE + "env_kwargs: {episode_length_s: 6}\nhyperparams: {n_epochs: 3}\n"))
    t, = expand_trials(cfg, tmp_path / "out")
    run = tmp_path / "out" / t.run_dir
    run.mkdir(parents=True)
    written = {"env": t.env, "algo": "ppo", "seed": 0, "n_timesteps": 256, "n_envs": 16, "wall_time_s": 3.0,
               "env_kwargs": {"episode_length_s": 6, "scenario": "seed000-sim"}, "eval_mean_reward_last": -5.0,
               "hyperparameters": {"n_epochs": 3, "gamma": 0.95}}
    (run / "config.json").write_text(json.dumps(written))
    assert trial_status(t) is None  # no model.zip: not finished
    (run / "model.zip").write_bytes(b"zip")
    assert trial_status(t)["result"]["eval_mean_reward_last"] == -5.0
    for key, other in (("seed", 1), ("n_timesteps", 512), ("hyperparameters", {"n_epochs": 5}),
                       ("env_kwargs", {"episode_length_s": 6, "scenario": "urban"})):
        (run / "config.json").write_text(json.dumps({**written, key: other}))
        assert trial_status(t) is None, key
    (run / "trial.json").write_text(json.dumps({"status": "running"}))  # interrupted
    assert trial_status(t) is None
